"""A 3 m square at 0.8 m/s flown as on a real vehicle through mavlink_bridge against quad_vehicle_emu (its 0.19 s
autopilot attitude response; telemetry 20 ms PX4 / 50 ms and bursts ArduPilot), with the bridge's and the
controller's own default timeouts, recorded and scored by `quadflight report --vehicle px4_quad.yaml`: the seed's
pd (config/control.yaml) and the real-vehicle profile (config/control_real.yaml). Beside it, the reference: the
same square flown on the autopilots' own software-in-the-loop builds (ArduCopter 4.6.0-dev SITL, PX4 v1.16.0
SIH), as measured when the bridge was flown on them (docs/bridge.md; PX4 SIH's rows from issue 28, over 23 runs).
The emulated PX4 also as PX4 SIH showed itself (`PX4 SIH-like`, two seeds of its estimate's wander each): its
0.23 s attitude lag, SIH's linear air drag (SIH_KDV / SIH_MASS: 1.0 m/s^2 per m/s), an estimated position 0.15 s
behind the truth wandering 0.6 m RMS horizontally and 0.8 m in height (60 s correlation, smoothed as EKF2's output
predictor does over EKF2_TAU_POS 0.25 s; velocity and attitude current), its clock at 0.985 of ours. Load: the
1-minute load average when the flight ended (2 cores; other work on the machine counts in it: a loaded machine
delays odometry and setpoints, which the stiff profiles feel first)."""

import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / 'test'))   # the graph helpers the bridge tests use

from bridge_graph import running_graph  # noqa: E402
from bridge_mission import CONTROL, REAL_PROFILE, fly_mission  # noqa: E402

SQUARE = [(0.0, 0.0, 2.0), (3.0, 0.0, 2.0), (3.0, 3.0, 2.0), (0.0, 3.0, 2.0), (0.0, 0.0, 2.0)]
SPEED_MPS = 0.8
PROFILES = {'seed pd (control.yaml)': None, 'control_real.yaml (pid)': REAL_PROFILE}
SE3_PROFILE = 'config/control_se3.yaml'
# PX4 v1.16 SIH as issue 28 measured it: attitude lag 0.23 s (tau = 0.23 - 1 / 6.5, quad_vehicle_emu.attitude);
# the estimate 0.4-0.8 m RMS off the truth (height 0.3-1.3 m), wandering 0.5 m a minute, 0.15 s behind; its clock
# at 0.984-0.993 of wall time; and SIH's own airframe: SIH_KDV 1.0 N/(m/s) on SIH_MASS 1.0 kg (sih_params.yaml)
PX4_SIH_LIKE = ('--attitude-tau-s', '0.076', '--estimator-lag-s', '0.15', '--estimator-wander-m', '0.6',
                '--estimator-wander-z-m', '0.8', '--estimator-wander-tau-s', '60', '--clock-rate', '0.985',
                '--drag-per-s', '1.0')
SIH_SEEDS = (1, 2)
SIH_PROFILES = {**PROFILES, 'control_se3.yaml (se3)': SE3_PROFILE}
PX4_SIH_RMSE_M = {'seed pd (control.yaml)': (0.34, 0.55), 'control_real.yaml (pid)': (0.43, 0.53),
                  'control_se3.yaml (se3)': (0.26, 0.27)}   # issue 28, PX4 v1.16.0 SIH
WITHIN = 0.30   # the goal: every SIH-like RMSE within 30 % of PX4 SIH's range
REFERENCE = [
    ('ArduCopter 4.6.0-dev SITL', 'seed pd, pid, se3', '', '0.058-0.069', '', '', ''),
    ('ArduCopter 4.6.0-dev SITL', 'the first flight', '', '0.072', '0.12', '', ''),
    ('PX4 v1.16.0 SIH', 'the first flight', '', '0.20-0.38 (its estimator wanders 0.1-0.3 m)', '', '', ''),
    *(('PX4 v1.16.0 SIH', label, '', f'{lo:.2f}-{hi:.2f}', '', '', '') for label, (lo, hi) in PX4_SIH_RMSE_M.items()),
    ('PX4 v1.16.0 SIH', "identify's profile", '', '0.56', '', '', ''),
]


def verdicts(sih_rmse: dict) -> list[str]:
    """Per profile: the SIH-like RMSEs against PX4 SIH's range, within WITHIN of it or not."""
    lines = []
    for label, (lo, hi) in PX4_SIH_RMSE_M.items():
        got = sih_rmse.get(label, [])
        if not got:
            lines.append(f'- {label}: no SIH-like flight flown to the end; PX4 SIH {lo:.2f}-{hi:.2f} m')
            continue
        ok = all((1 - WITHIN) * lo <= r <= (1 + WITHIN) * hi for r in got)
        missing = len(SIH_SEEDS) - len(got)
        lines.append(f'- {label}: PX4 SIH-like {" / ".join(f"{r:.3f}" for r in got)} m against PX4 SIH '
                     f'{lo:.2f}-{hi:.2f} m: {"within" if ok else "NOT within"} {WITHIN:.0%} '
                     f'({(1 - WITHIN) * lo:.2f}-{(1 + WITHIN) * hi:.2f} m)'
                     + (f'; {missing} of {len(SIH_SEEDS)} not flown to the end' if missing else ''))
    return lines


def main():
    rows, sih_rmse = [], {}
    runs = [(f'quad_vehicle_emu {flavour}', flavour, label, profile, ()) for flavour in ('px4', 'ardupilot')
            for label, profile in PROFILES.items()]
    runs += [(f'quad_vehicle_emu px4, PX4 SIH-like (seed {seed})', 'px4', label, profile,
              (*PX4_SIH_LIKE, '--seed', str(seed))) for label, profile in SIH_PROFILES.items() for seed in SIH_SEEDS]
    for vehicle, flavour, label, profile, extra in runs:
        with tempfile.TemporaryDirectory() as tmp, running_graph(Path(tmp)) as (procs, observer):
            try:
                flight = fly_mission(procs, observer, Path(tmp), flavour, SQUARE, SPEED_MPS, profile=profile,
                                     vehicle_extra=extra)
            except AssertionError as exc:   # e.g. a stalled graph's stale setpoints ended the hand-over: a row
                print(f'{vehicle} {label}: {exc}', file=sys.stderr)
                rows.append((vehicle, label, 'not flown to the end: ' + str(exc).split(':')[0], '', '', '',
                             f'{os.getloadavg()[0]:.1f}'))
                continue
            m = flight.metrics
            print(f'{vehicle} {label}: rmse {m["rmse_m"]:.3f} m', file=sys.stderr)
            if extra:
                sih_rmse.setdefault(label, []).append(m['rmse_m'])
            rows.append((vehicle, label,
                         f'{m["time_planned_s"]:.2f} / {m["time_actual_s"]:.2f}', f'{m["rmse_m"]:.3f}',
                         f'{m["max_error_m"]:.3f}', f'{m["waypoint_miss_max_m"]:.3f}', f'{os.getloadavg()[0]:.1f}'))
    print('## Bridge flight: a 3 m square at 0.8 m/s through mavlink_bridge\n')
    print(__doc__.replace('\n', ' ').strip() + ' ' + f'Control profiles over {Path(CONTROL).name}; scored window '
          'and tolerances: the vehicle\'s (10 cm, 0.1 m/s, settle 3 s).\n')
    print('| vehicle | control | time planned / actual (s) | RMSE (m) | max error (m) | waypoint miss max (m) | load |')
    print('|---|---|---|---|---|---|---|')
    for row in rows + REFERENCE:
        print('| ' + ' | '.join(row) + ' |')
    print(f'\nThe PX4 SIH-like emulator against PX4 SIH (goal: within {WITHIN:.0%} of its range):\n')
    print('\n'.join(verdicts(sih_rmse)))


if __name__ == '__main__':
    main()
