"""mavlink_bridge against an autopilot's real telemetry: the setpoint path's publish-to-wire latency
and the bridge's CPU while the vehicle streams what a real one streams. Setpoints at 50 Hz for RUN_S, today's
code and, in the same run, the code before the receive-path change (BASELINE, from git), alternating, REPEATS
runs each (the
medians; lost summed), with no busy loops of ours and beside BUSY busy-looping processes. The vehicle doubles
speak MAVLink 2 (pymavlink's dialect encoders) over UDP:

- PX4: LOCAL_POSITION_NED, ATTITUDE_QUATERNION, ATTITUDE and HIGHRES_IMU at 50 Hz each (200 messages/s), one
  datagram per message as PX4's mavlink module sends them (Mavlink::send_finish per message).
- ArduPilot: everything due in one scheduler tick in one datagram (GCS_MAVLINK::update_send fills the UART
  buffer, the UDP link sends it per tick): the messages the bridge asks for with SET_MESSAGE_INTERVAL
  (LOCAL_POSITION_NED, ATTITUDE_QUATERNION, SCALED_IMU) at 50 Hz, and ArduCopter's SRx_ stream groups
  (GCS_Common.cpp STREAM_*_msgs) at a companion link's usual rates: EXTRA1, POSITION, RAW_SENSORS, EXTRA2 at
  10 Hz, EXTENDED_STATUS, RC_CHANNELS, EXTRA3 at 2 Hz (286 messages/s)."""

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bench_bridge as bb  # noqa: E402
from bench_bridge import HOVER_THROTTLE, mavlink  # noqa: E402
from busy import busy_loops  # noqa: E402

from quad_common.domains import isolated_domain  # noqa: E402

BASELINE = '5a87bc8'   # main's receive and setpoint paths before this change
# The floor in the same alternation (bench/bridge_floor.py: the least a Python rclpy bridge with this telemetry can
# do); BENCH_FLOOR=0 leaves it out
FLOOR = os.environ.get('BENCH_FLOOR', '1') != '0'
FLOOR_LABEL = 'floor: bench/bridge_floor.py'
# More commits to run beside it, e.g. BENCH_ALSO=f68c54c (the receive path before its batches read past one datagram)
ALSO = tuple(c for c in os.environ.get('BENCH_ALSO', '').split(',') if c)
# Today's code also at these realtime_priority values (SCHED_FIFO, docs/bridge.md), e.g. BENCH_RT=20
RT = tuple(int(p) for p in os.environ.get('BENCH_RT', '').split(',') if p)
RATE_HZ = 50.0
RUN_S = float(os.environ.get('BENCH_RUN_S', 10.0))
BUSY = int(os.environ.get('BENCH_BUSY', 4))
# Also with the bench's own process (its publisher, the vehicle double) under SCHED_FIFO at this priority during
# the window, as a real stack runs its controller: what p99 the bridge gives when the caller is not the one
# waiting for the CPU (e.g. BENCH_CALLER_RT=20; the bridge and the busy loops it starts are not affected)
CALLER_RT = tuple(int(p) for p in os.environ.get('BENCH_CALLER_RT', '').split(',') if p)
LOAD_SETTLE_S = 90.0   # busy loops run this long before a section's first window: 1 - e^-1.5 of their load shows
REPEATS = int(os.environ.get('BENCH_REPEATS', 3))   # alternating runs per row: a shared machine's load drifts
ROOT = Path(bb.ROOT)

# ArduCopter's stream groups (GCS_Common.cpp) as message names, with the rate (Hz) a companion link sets
ARDUPILOT_GROUPS = (
    (10, ('ATTITUDE', 'SIMSTATE', 'AHRS2', 'PID_TUNING')),                                     # EXTRA1
    (10, ('GLOBAL_POSITION_INT',)),                              # POSITION (LOCAL_POSITION_NED: requested)
    (10, ('RAW_IMU', 'SCALED_IMU2', 'SCALED_IMU3', 'SCALED_PRESSURE', 'SCALED_PRESSURE2')),    # RAW_SENSORS
    (10, ('VFR_HUD',)),                                                                        # EXTRA2
    (2, ('SYS_STATUS', 'POWER_STATUS', 'MEMINFO', 'MISSION_CURRENT', 'GPS_RAW_INT',
         'NAV_CONTROLLER_OUTPUT')),                                                            # EXTENDED_STATUS
    (2, ('SERVO_OUTPUT_RAW', 'RC_CHANNELS')),                                                  # RC_CHANNELS
    (2, ('AHRS', 'SYSTEM_TIME', 'BATTERY_STATUS', 'EKF_STATUS_REPORT', 'VIBRATION')),         # EXTRA3
)
ARDUPILOT_REQUESTED = ('ATTITUDE_QUATERNION', 'LOCAL_POSITION_NED', 'SCALED_IMU')
HOVERING = {'ATTITUDE_QUATERNION': {'q1': 1.0}, 'LOCAL_POSITION_NED': {'z': -1.0},
            'HIGHRES_IMU': {'zacc': -9.81}, 'SCALED_IMU': {'zacc': -1000}, 'RAW_IMU': {'zacc': -1000},
            'SYS_STATUS': {'voltage_battery': 16000, 'current_battery': 500, 'battery_remaining': 80},
            'BATTERY_STATUS': {'voltages': [4000] * 4 + [0xFFFF] * 6, 'current_battery': 500,
                               'battery_remaining': 80}}


def message(name, t_s, **fields):
    """A message of the dialect with every field zero but `fields` (and HOVERING's), stamped t_s after boot."""
    cls = getattr(mavlink, f'MAVLink_{name.lower()}_message')
    fields = {**HOVERING.get(name, {}), 'time_boot_ms': int(t_s * 1e3), 'time_usec': int(t_s * 1e6), **fields}
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths))   # array_lengths are in wire order
    args = []
    for field, kind in zip(cls.fieldnames, cls.fieldtypes):
        n = lengths[field]
        zero = b'' if kind == 'char' else ([0] * n if n else (0.0 if kind in ('float', 'double') else 0))
        args.append(fields.get(field, zero))
    return cls(*args)


class Px4Vehicle(bb.BenchVehicle):
    """PX4: the four 50 Hz streams, one datagram per message."""

    STREAMS = ('LOCAL_POSITION_NED', 'ATTITUDE_QUATERNION', 'ATTITUDE', 'HIGHRES_IMU')

    def telemetry(self, mav, t_s, tick):
        return [message(name, t_s).pack(mav) for name in self.STREAMS]


class ArduPilotVehicle(bb.BenchVehicle):
    """ArduCopter in GUIDED_NOGPS's world: its ids, mode numbers and parameters; a burst per 50 Hz tick."""

    autopilot = 3       # MAV_AUTOPILOT_ARDUPILOTMEGA
    initial_mode = 0    # STABILIZE
    params = {'GUID_OPTIONS': (8, mavlink.MAV_PARAM_TYPE_INT32),
              'MOT_THST_HOVER': (HOVER_THROTTLE, mavlink.MAV_PARAM_TYPE_REAL32),
              'ATC_ANGLE_BOOST': (1, mavlink.MAV_PARAM_TYPE_INT8)}

    @staticmethod
    def custom_mode(param2, param3):
        return int(param2)

    def telemetry(self, mav, t_s, tick):
        names = list(ARDUPILOT_REQUESTED)
        for rate_hz, group in ARDUPILOT_GROUPS:
            if tick % int(round(1.0 / (rate_hz * self.period_s))) == 0:
                names += group
        return [b''.join(bytes(message(name, t_s).pack(mav)) for name in names)]


VEHICLES = {'px4': Px4Vehicle, 'ardupilot': ArduPilotVehicle}


def baseline_src(tmp: Path, commit: str = BASELINE) -> Path:
    (tmp / commit).mkdir()
    archive = subprocess.run(['git', '-C', str(ROOT), 'archive', commit, 'src'], capture_output=True, check=True)
    subprocess.run(['tar', '-x', '-C', str(tmp / commit)], input=archive.stdout, check=True)
    return tmp / commit / 'src'


def python_path(src: Path) -> str:
    return os.pathsep.join(str(src / p) for p in sorted(os.listdir(src)))


def caller_realtime(priority):
    """Every thread of this process under SCHED_FIFO at priority (0: SCHED_OTHER), not passed on to children."""
    policy = os.SCHED_FIFO | os.SCHED_RESET_ON_FORK if priority else os.SCHED_OTHER
    for tid in os.listdir('/proc/self/task'):
        try:
            os.sched_setscheduler(int(tid), policy, os.sched_param(priority))
        except ProcessLookupError:
            pass


def run_once(autopilot, src, env, domain, extra=(), caller_rt=0, floor=False) -> dict:
    """One window of the bridge of `src` (floor: bench/bridge_floor.py instead, with today's quad_common)."""
    bridge = ['-m', 'quad_bridge.mavlink_bridge_node', '--ros-args', '-p', 'fcu_url:=udpout:127.0.0.1:{port}',
              '-p', f'hover_throttle:={HOVER_THROTTLE}', '-p', f'autopilot:={autopilot}',
              '-p', 'setpoint_rate_hz:=50.0', '-p', 'setpoint_timeout_s:=1.0', '-p', 'setpoint_source:=bench_bridge',
              *extra]
    if floor:
        bridge = [str(ROOT / 'bench' / 'bridge_floor.py'), '{port}', str(HOVER_THROTTLE), '--ros-args']
    env = dict(env, PYTHONPATH=python_path(src) + os.pathsep + env.get('PYTHONPATH', ''))
    bench = bb.Bench(bridge, env, domain, VEHICLES[autopilot]())
    try:
        bench.warm_up(not floor)
        caller_realtime(caller_rt)
        try:
            result = bench.measure(RATE_HZ, RUN_S)
        finally:
            caller_realtime(0)
        result['load'] = os.getloadavg()[0]
        return result
    finally:
        bench.close()


def run_retried(row, failed: list, *args, **kwargs) -> dict:
    """run_once, once more after a start that never streamed (said in `failed` and under the table, never
    hidden; a second failure ends the bench)."""
    try:
        return run_once(*args, **kwargs)
    except RuntimeError as exc:
        print(f'{row}: {exc}', file=sys.stderr)
        failed.append((row, str(exc).splitlines()[-1]))
        return run_once(*args, **kwargs)


def main():
    runs, failed = {}, []
    with tempfile.TemporaryDirectory() as tmp, isolated_domain() as (domain, env):
        codes = [(f'before ({BASELINE})', baseline_src(Path(tmp)), ())]
        codes += [(f'at {c}', baseline_src(Path(tmp), c), ()) for c in ALSO] + [('today', ROOT / 'src', ())]
        codes += [(f'today, realtime_priority {p}', ROOT / 'src', ('-p', f'realtime_priority:={p}')) for p in RT]
        codes += [(FLOOR_LABEL, ROOT / 'src', ())] if FLOOR else []
        for busy in (0, BUSY):
            with busy_loops(busy, settle_s=LOAD_SETTLE_S):
                for _ in range(REPEATS):
                    for autopilot in VEHICLES:
                        for caller in (0, *CALLER_RT):
                            for label, src, extra in codes:
                                row = (autopilot, label, busy, caller)
                                r = run_retried(row, failed, autopilot, src, env, domain, extra, caller,
                                                floor=label == FLOOR_LABEL)
                                print(f'{autopilot} {label} busy={busy} caller={caller}: {r}', file=sys.stderr)
                                runs.setdefault(row, []).append(r)
    print('### MAVLink bridge with an autopilot\'s real telemetry\n')
    doc = __doc__.replace('BASELINE', BASELINE).replace('RUN_S', f'{RUN_S:.0f} s').replace('BUSY', str(BUSY))
    head, *vehicles = doc.replace('REPEATS', str(REPEATS)).split('\n- ')
    also = ''.join(f' Beside them `at {c}`: the code of commit {c}, from git, in the same alternation.' for c in ALSO)
    also += ''.join(f' `today, realtime_priority {p}`: today\'s code with every thread under SCHED_FIFO {p}.'
                    for p in RT)
    also += ''.join(f' Publisher `FIFO {p}`: the bench\'s own process (the publisher, the vehicle double) under '
                    f'SCHED_FIFO {p} during the window, as a real stack would run its controller; `ordinary`: '
                    'SCHED_OTHER, beside the busy loops.' for p in CALLER_RT[:1])
    print(' '.join(head.split()) + '\n')
    print('\n'.join('- ' + ' '.join(v.split()) for v in vehicles) + '\n')
    if FLOOR:
        also += (f' `{FLOOR_LABEL}`: the least a Python rclpy bridge can do with this telemetry (the setpoint echo of '
                 'bench/bridge_echo.py, and a thread that publishes a serialized `odom` / `imu` for each position '
                 '/ IMU datagram, nothing decoded, checked or stamped): what the goal is measured against.')
    if also:
        print(also.strip() + '\n')
    print('Latency: publishing `cmd/attitude_thrust` to its SET_ATTITUDE_TARGET datagram arriving at the vehicle '
          'double (kernel receive time); p99 range: the lowest and highest run\'s p99. CPU: the bridge process\'s '
          'user + system time over the window, % of one '
          f'core. Load: the 1-minute load average at the end of the window ({os.cpu_count()} cores; other work on '
          f'the machine counts in it; the busy loops run through the whole section, from {LOAD_SETTLE_S:.0f} s before '
          'its first window). Goal: p99 < 2 ms and CPU < 5 % at 50 Hz.\n')
    print('| vehicle | code | publisher | busy loops | load | p50 ms | p99 ms | p99 range ms | CPU % | lost | '
          'odom gap ms |')
    print('|---|---|---|---|---|---|---|---|---|---|---|')
    for (autopilot, label, busy, caller), rs in runs.items():
        med = {k: float(np.median([r[k] for r in rs])) for k in ('load', 'p50', 'p99', 'cpu_pct', 'odom_gap_ms')}
        lost, n = sum(r['lost'] for r in rs), sum(r['n'] for r in rs)
        p99 = [r['p99'] for r in rs]
        print(f'| {autopilot} | {label} | {f"FIFO {caller}" if caller else "ordinary"} | {busy} | {med["load"]:.1f} '
              f'| {med["p50"]:.2f} | {med["p99"]:.2f} | {min(p99):.1f}-{max(p99):.1f} | {med["cpu_pct"]:.1f} | '
              f'{lost}/{n} | {med["odom_gap_ms"]:.0f} |')
    if failed:
        print(f'\nStarts that never streamed and were run again ({len(failed)}):\n')
        print('\n'.join(f'- {row[0]}, {row[1]}, busy {row[2]}, publisher {row[3]}: {why}' for row, why in failed))


if __name__ == '__main__':
    main()
