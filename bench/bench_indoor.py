"""Indoor flight: what the controller flies from, scored where the vehicle really is.

The 3 m square at 0.8 m/s on the offline chain of quad_bringup.emulated.offline_chain (the emulator's own pieces under
position_controller's ControlLoop at 100 Hz: its vehicle, the attitude shaping behind the autopilot's loop, the
estimate, the telemetry delay line; no processes, MAVLink or load), on two plants: the default emulated autopilot
(0.19 s attitude lag, no drag) and PX4 SIH as fitted to its recorded flights (0.105 s dead time before a 0.05 s
response, SIH's air drag 1 m/s^2 per m/s). RMSE of the truth (where the vehicle is, every 10 ms) against the plan,
over the plan plus 3 s. Three sources of the controller's state. GPS-like estimate: the autopilot's estimate as PX4
SIH's EKF2 gave it with its simulated GPS (PX4_SIH_FITTED: current, wandering 0.18 m / 0.3 m in height over
4 s, velocity wander 0.2 m/s), odometry at 50 Hz, 20 ms late. Autopilot estimate = truth: the best an estimator
fusing the motion capture can publish (the truth's position and velocity, odometry at 50 Hz, 20 ms late), an upper
bound for external vision through the autopilot. Motion capture direct: position_controller `state_source:
external_pose`, the truth's position + 1 mm noise at 100 Hz, 10 ms late (the stand-in's setting), the velocity
from quad_control.pose_state's filter at the `pose_acceleration_mps2` given (5: the default).
Autopilot estimate fused from the pose (default emulator only): the estimate quad_vehicle_emu.external_vision
fuses from the motion-capture pose the bridge forwards (1 mm noise, 30 Hz: external_pose_rate_hz, 10 ms old at
PX4, EKF2_EV_DELAY 5 ms: with the 5 ms half step EKF2 subtracts itself, the pose's age), odometry as above.
Goal: <= 5 cm for the real-vehicle default (control_real.yaml)."""

import sys
import tempfile
from pathlib import Path

import yaml

from quad_bringup.emulated import offline_chain as chain
from quad_bringup.emulated.mission_flight import REAL_PROFILE
from quad_common.paths import resolve_config
from quad_common.yaml_io import load_yaml
from quad_control.parameters import profile_with

DEFAULT_EMULATOR = ('--attitude-tau-s', '0.036', '--estimator-lag-s', '0', '--estimator-wander-m', '0',
                    '--estimator-wander-z-m', '0', '--estimator-wander-tau-s', '60', '--drag-per-s', '0')
_FITTED = dict(zip(chain.PX4_SIH_FITTED[::2], chain.PX4_SIH_FITTED[1::2]))
PERFECT_ESTIMATE = {'--estimator-lag-s': '0', '--estimator-wander-m': '0', '--estimator-wander-z-m': '0',
                    '--estimator-velocity-wander-mps': '0', '--estimator-velocity-wander-z-mps': '0',
                    '--estimator-velocity-noise-mps': '0,0,0'}
SIH_TRUTH_ESTIMATE = tuple(x for kv in {**_FITTED, **PERFECT_ESTIMATE}.items() for x in kv)
PLANTS = {'default emulator': (DEFAULT_EMULATOR, DEFAULT_EMULATOR),
          'PX4 SIH fitted (drag)': (chain.PX4_SIH_FITTED, SIH_TRUTH_ESTIMATE)}
PROFILES = {'pd (control.yaml)': None, 'control_real.yaml (pid)': REAL_PROFILE,
            'control_se3.yaml (se3)': 'config/control_se3.yaml'}
MOCAP = (0.001, 0.01, 100.0)   # noise m, latency s, rate Hz
VISION = (0.001, 0.01, 30.0, 5.0)   # noise m, age at the autopilot s, rate Hz, EKF2_EV_DELAY ms
ACCELERATIONS = (5.0, 20.0)   # pose_acceleration_mps2 flown (5: the default)
SEEDS = (0, 1)


def with_pose_acceleration(profile, acceleration_mps2: float, directory: Path) -> str:
    """The profile with pose_acceleration_mps2 set, as a file."""
    content = profile_with(load_yaml(resolve_config(profile or chain.CONTROL)),
                           {'pose_acceleration_mps2': acceleration_mps2})
    path = directory / f'{Path(profile or chain.CONTROL).stem}_{acceleration_mps2:g}.yaml'
    path.write_text(yaml.safe_dump(content))
    return str(path)


def main():
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for plant, (gps_like, truth_estimate) in PLANTS.items():
            for label, profile in PROFILES.items():
                cells = []
                gps = [chain.fly_chain_offline(profile, s, options=gps_like, truth=True) for s in SEEDS] \
                    if gps_like is not truth_estimate else None
                cells.append(' / '.join(f'{100 * r:.1f}' for r in gps) if gps else 'n/a (no GPS model)')
                cells.append(f'{100 * chain.fly_chain_offline(profile, 0, options=truth_estimate, truth=True):.1f}')
                if plant == 'default emulator':
                    fused = [chain.fly_chain_offline(profile, s, options=truth_estimate, truth=True, vision=VISION)
                             for s in SEEDS]
                    cells.append(' / '.join(f'{100 * r:.1f}' for r in fused))
                else:
                    cells.append('n/a')
                for a in ACCELERATIONS:
                    flown = with_pose_acceleration(profile, a, Path(tmp))
                    got = [chain.fly_chain_offline(flown, s, options=truth_estimate, mocap=MOCAP, truth=True)
                           for s in SEEDS]
                    cells.append(' / '.join(f'{100 * r:.1f}' for r in got))
                rows.append((plant, label, *cells))
                print(f'{plant} {label}: {cells}', file=sys.stderr)
    print('## Indoor flight: the controller on motion capture, the truth against the plan\n')
    print(__doc__.replace('\n', ' ').strip() + '\n')
    print('| plant | control | GPS-like estimate (cm, seeds 0 / 1) | autopilot estimate = truth (cm) | '
          'autopilot estimate fused from the pose (cm, seeds 0 / 1) | '
          'motion capture direct, pose_acceleration 5: default (cm) | motion capture direct, 20 (cm) |')
    print('|---|---|---:|---:|---:|---:|---:|')
    for row in rows:
        print('| ' + ' | '.join(row) + ' |')


if __name__ == '__main__':
    main()
