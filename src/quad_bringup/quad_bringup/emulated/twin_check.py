"""An emulated flight's twin, checked: a bridge flight against quad_vehicle_emu (quad_bringup.emulated.mission_flight,
control_real.yaml), `quadflight identify` and `quadflight replay` run on its bag as a user runs them, the twin with
fresh odometry beside it, and identify's margin check against the emulator's own attitude loop at the margin the
check states. Shared by the replay graph test (test/emulator/test_replay_emulator.py) and the twin bench
(bench/bench_twin.py); not part of a flight."""

import subprocess
import sys
import tempfile
from pathlib import Path

from quad_bringup.emulated.mission_flight import REAL_PROFILE, fly_mission
from quad_bringup.emulated.offline_chain import SQUARE
from quad_bringup.emulated.vehicle_graph import VEHICLE_FILE, running_graph
from quad_common.paths import REPO_ROOT

SPEED_MPS = 1.0           # the square at the speed identify asks for
TRACE_GOAL = 0.35          # the twin's trace error RMSE under 35 % of the flight's tracking RMSE
# stiffer xy gains over control_real.yaml: what the margin check refuses or accepts, and the emulator's loop at
# the margin the check states
MARGIN_PROFILES = {'control_real.yaml (kp 2 / kd 2.5)': {}, 'kp 4 / kd 3': {'kp_x': 4.0, 'kp_y': 4.0, 'kd_x': 3.0,
                                                                             'kd_y': 3.0},
                   'kp 5 / kd 5': {'kp_x': 5.0, 'kp_y': 5.0, 'kd_x': 5.0, 'kd_y': 5.0},
                   'kp 8 / kd 4': {'kp_x': 8.0, 'kp_y': 8.0, 'kd_x': 4.0, 'kd_y': 4.0}}


def emulator_flight(flavour, out_dir: Path, waypoints=SQUARE, speed_mps=SPEED_MPS):
    """A bridge flight against the emulated `flavour` (quad_bringup.emulated.mission_flight.fly_mission,
    control_real.yaml): a MissionFlight whose bag stays under out_dir."""
    with running_graph(out_dir) as (procs, observer):
        return fly_mission(procs, observer, out_dir, flavour, waypoints, speed_mps,
                           bridge_params={'setpoint_timeout_s': 1.0},     # a busy 2-core machine's stalls
                           controller_params={'odom_timeout_s': 1.0})


def cli(*args):
    """`quadflight ARGS` in a process of its own, from the checkout's root."""
    return subprocess.run([sys.executable, '-m', 'quad_bringup.cli', *map(str, args)], capture_output=True,
                          text=True, cwd=REPO_ROOT, timeout=600)


def replay_numbers(stdout: str) -> dict:
    """The cm figures `quadflight replay` prints: flight, twin, trace (closed loop) and open (open loop)."""
    closed, opened = stdout.splitlines()[0], next(x for x in stdout.splitlines() if x.startswith('open loop'))

    def cm(line, what):
        return float(line.split(f'{what} RMSE ')[1].split(' cm')[0])
    source = next((x.split(', ', 1)[1] for x in stdout.splitlines() if x.startswith("the twin's controller flew")),
                  'fresh')
    return {'flight': cm(closed, 'flight'), 'twin': cm(closed, 'twin'), 'trace': cm(closed, '|twin - flight|'),
            'open': cm(opened, '|twin - flight|'), 'telemetry': source}


def identify_and_replay(bag: Path, out: Path) -> tuple[dict, dict]:
    """(`quadflight identify` on the bag: check_bag's answer, `quadflight replay` on its model: replay_numbers)."""
    from quad_bringup.commands.identify import check_bag
    model = out / 'model.yaml'
    done = cli('identify', bag, '--vehicle', VEHICLE_FILE, '--out', out / 'profile.yaml', '--model-out', model)
    if done.returncode != 0:
        raise RuntimeError(f'quadflight identify refused: {done.stderr.strip()}')
    checked = check_bag(bag, REAL_PROFILE, VEHICLE_FILE)
    done = cli('replay', bag, '--vehicle', model, '--control-profile', REAL_PROFILE, '--figure', out / 'replay.png')
    if done.returncode != 0:
        raise RuntimeError(f'quadflight replay failed: {done.stderr.strip()}')
    return checked, replay_numbers(done.stdout)


def fresh_twin(bag: Path, model: Path) -> dict:
    """replay's twin with fresh odometry every tick (what replay flew before it read the bag's telemetry)."""
    from quad_bringup.analysis.report import load_flight
    from quad_bringup.offline.closed_loop import load_control_profile
    from quad_bringup.offline.replay import replay
    controller, gains = load_control_profile(REAL_PROFILE)
    r = replay(load_flight(bag), model, controller, gains, telemetry=(0.0, 0.0))
    return {'twin': 100 * r['twin_rmse_m'], 'trace': 100 * r['trace_rmse_m']}


def margin_rows(bag: Path):
    """Per MARGIN_PROFILES: the margin check's verdict on the bag (check_bag with that base) and the emulator's own
    attitude structure (quad_vehicle_emu.attitude: the quaternion loop behind its shaping, telemetry through its
    DelayLine; stability.hold_on_autopilot without `response`) holding at the lag and latency the check states."""
    import yaml

    from quad_bringup.commands.identify import check_bag
    from quad_bringup.offline.closed_loop import control_profile
    from quad_bringup.offline.stability import hold_on_autopilot
    from quad_common.paths import resolve_config
    from quad_common.yaml_io import load_yaml
    from quad_control.parameters import profile_with
    base = load_yaml(resolve_config(REAL_PROFILE))
    rows = []
    with tempfile.TemporaryDirectory(prefix='bench_twin-') as tmp:
        for label, over in MARGIN_PROFILES.items():
            path = Path(tmp) / 'base.yaml'
            path.write_text(yaml.safe_dump(profile_with(base, over)))
            checked = check_bag(bag, str(path), VEHICLE_FILE)
            m, t = checked['margin'], checked['telemetry']
            controller, gains = control_profile(checked['written'])
            emu = hold_on_autopilot(VEHICLE_FILE, controller, gains, m.lag_s, m.latency_s, burst_s=t.burst_s,
                                    telemetry_rate_hz=t.rate_hz)
            rows.append((label, m, checked['refusal'], emu))
    return rows
