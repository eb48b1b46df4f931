"""A failure once seen on ArduCopter, measured: a vehicle hovering in GUIDED_NOGPS through mavlink_bridge and
position_controller (its defaults: 0.2 s odometry timeout; the bridge's stale-setpoint timeout) while
trajectory_node plans and publishes a 10,000-point trajectory. The longest gap between `odom` messages (their
arrival at a probe node) and between the controller's ticks (the stamps of `cmd/attitude_thrust`), from
trajectory_node's start until 2 s after the controller has the plan, against the same in the 3 s before; and
whether the hand-over survived (stale odometry / stale setpoints in the logs from the 3 s before on, the mode
at the end). On a quiet machine and beside two busy-looping processes (the busy 2-core machine), for today's
code and, in the same run, for the code before its fix (commit BASELINE, checked out from git into a temporary
folder) on the same emulated vehicle."""

import json
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from busy import busy_loops
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Imu

from quad_bringup.emulated.vehicle_graph import Processes, enter_offboard, free_udp_port, running_graph
from quad_common.conversions import stamp_to_s

ROOT = Path(__file__).resolve().parent.parent

BASELINE = 'f5909f4'
HOVER = (0.0, 0.0, 2.0)
# a 2 m square flown at 2 cm/s: a 100 s plan, sampled at 100 Hz as trajectory_node publishes it
SLOW_SQUARE = [HOVER, (0.5, 0.0, 2.0), (0.5, 0.5, 2.0), (0.0, 0.5, 2.0), HOVER]
SLOW_SPEED_MPS = 0.02
BEFORE_S = 3.0
AFTER_S = 2.0


def probe_main(out_path: str):
    """The probe, a process of its own (the observer's executor decodes the 1.8 MB trajectory, which would stall
    a probe beside it): arrival times of odom and stamps of cmd/attitude_thrust, written to out_path as JSON on
    SIGTERM."""
    import json
    import signal

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    rclpy.init(signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = rclpy.create_node('gap_probe')
    odom, ticks = [], []
    node.create_subscription(Odometry, 'odom', lambda m: odom.append(time.time()), 1000)
    node.create_subscription(Imu, 'cmd/attitude_thrust', lambda m: ticks.append(stamp_to_s(m.header.stamp)), 1000)
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    while not stop:
        executor.spin_once(timeout_sec=0.05)
    Path(out_path).write_text(json.dumps({'odom': odom, 'ticks': ticks}))


def longest_gap_ms(series, t0, t1) -> float:
    t = np.sort(np.array(series))
    t = t[(t >= t0) & (t <= t1)]
    return float(np.diff(t).max() * 1e3) if len(t) > 1 else float('nan')


def events(log: str, text: str, since_s: float) -> int:
    """Log lines with `text` stamped (rcutils' [seconds.nanoseconds]) at or after since_s (wall clock)."""
    stamps = [float(m.group(1)) for line in log.splitlines() if text in line
              for m in [re.search(r'\[(\d+\.\d+)\]', line)] if m]
    return sum(t >= since_s for t in stamps)


def baseline_src(tmp: Path) -> Path:
    """src/ (and config/ beside it) of the BASELINE commit, extracted with git archive (no worktree left)."""
    archive = subprocess.run(['git', '-C', str(ROOT), 'archive', BASELINE, 'src', 'config'], capture_output=True,
                             check=True)
    subprocess.run(['tar', '-x', '-C', str(tmp)], input=archive.stdout, check=True)
    return tmp / 'src'


def run_once(src: Path | None, busy: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp, running_graph(Path(tmp)) as (procs, observer):
        ours = procs if src is None else Processes(procs.env, Path(tmp), procs.namespace, src_root=src)
        probe_out = Path(tmp) / 'probe.json'
        procs.start('probe', [str(Path(__file__).resolve()), '--probe', str(probe_out), '--ros-args'])
        try:
            with busy_loops(busy):
                port = free_udp_port()
                procs.vehicle('ardupilot', f'udpout:127.0.0.1:{port}', position=HOVER,
                              extra=('--param', 'GUID_OPTIONS=8'))
                ours.bridge(f'udpin:127.0.0.1:{port}', autopilot='ardupilot')
                config = (src.parent if src else ROOT) / 'config'
                ours.start('controller', ['-m', 'quad_control.position_controller_node', '--ros-args',
                                          '-p', f'vehicle:={config}/vehicles/px4_quad.yaml'])   # its defaults
                enter_offboard(observer, 'ardupilot', bridge_counts_setpoints=src is None)
                time.sleep(BEFORE_S)                 # the window measured before (wall time is what is measured)
                started = time.time()
                flat = ','.join(str(float(c)) for wp in SLOW_SQUARE for c in wp)
                ours.start('trajectory', ['-m', 'quad_trajectory.trajectory_node', '--ros-args',
                                          '-p', f'waypoints:=[{flat}]', '-p', f'speed_mps:={SLOW_SPEED_MPS}',
                                          '-p', 'start_delay_s:=1.0',
                                          '-p', f'vehicle_file:={config}/vehicles/px4_quad.yaml'])
                observer.wait_for(lambda: observer.trajectory is not None, 'the trajectory')
                # the controller has the plan once its references follow it (its start is 1 s after the stamp)
                start_s = stamp_to_s(observer.trajectory.header.stamp)
                observer.wait_for(lambda: observer.references and observer.references[-1][0] > start_s + 0.5,
                                  'the controller to fly the plan', 120.0)
                held = time.time()
                time.sleep(AFTER_S)
                end = time.time()
                mode = observer.link()[1].get('mode')
                procs.stop('probe')
                seen = json.loads(probe_out.read_text())
        finally:
            if ours is not procs:
                ours.stop_all()
        return {'odom_before_ms': longest_gap_ms(seen['odom'], started - BEFORE_S, started),
                'odom_during_ms': longest_gap_ms(seen['odom'], started, end),
                'tick_before_ms': longest_gap_ms(seen['ticks'], started - BEFORE_S, started),
                'tick_during_ms': longest_gap_ms(seen['ticks'], started, end),
                'points': len(observer.trajectory.points), 'arrival_s': held - started, 'mode': mode,
                'odom_stale': events(ours.log('controller'), 'odom stale (', started - BEFORE_S),
                'setpoints_stale': events(ours.log('bridge'), 'setpoints stale', started - BEFORE_S)}


def main():
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        old = baseline_src(Path(tmp))
        for busy in (0, 2):
            for label, src in ((f'before the fix ({BASELINE})', old), ('today', None)):
                r = run_once(src, busy)
                print(f'{label} busy={busy}: {r}', file=sys.stderr)
                rows.append((label, busy, r))
    print('## Bridge and controller while a 10,000-point trajectory arrives\n')
    print(__doc__.replace('\n', ' ').replace('BASELINE', BASELINE).strip() + '\n')
    print('| code | busy loops | points | planned + taken (s) | odom gap before / during (ms) | '
          'tick gap before / during (ms) | stale odometry | stale setpoints | mode after |')
    print('|---|---|---|---|---|---|---|---|---|')
    for label, busy, r in rows:
        print(f'| {label} | {busy} | {r["points"]} | {r["arrival_s"]:.2f} | {r["odom_before_ms"]:.0f} / '
              f'{r["odom_during_ms"]:.0f} | {r["tick_before_ms"]:.0f} / {r["tick_during_ms"]:.0f} | '
              f'{r["odom_stale"]} | {r["setpoints_stale"]} | {r["mode"]} |')


if __name__ == '__main__':
    if len(sys.argv) > 2 and sys.argv[1] == '--probe':
        probe_main(sys.argv[2])
    else:
        main()
