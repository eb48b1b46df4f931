"""A 3 m square at 0.8 m/s flown as on a real vehicle through mavlink_bridge against quad_vehicle_emu (its 0.19 s
autopilot attitude response; telemetry 20 ms PX4 / 50 ms and bursts ArduPilot), with the bridge's and the
controller's own default timeouts, recorded and scored by `quadflight report --vehicle px4_quad.yaml`: the seed's
pd (config/control.yaml) and the real-vehicle profile (config/control_real.yaml). Beside it, the reference: the
same square flown on the autopilots' own software-in-the-loop builds (ArduCopter 4.6.0-dev SITL, PX4 v1.16.0
SIH), as measured when the bridge was first flown on them (docs/bridge.md)."""

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
REFERENCE = [
    ('ArduCopter 4.6.0-dev SITL', 'seed pd, pid, se3', '', '0.058-0.069', '', ''),
    ('ArduCopter 4.6.0-dev SITL', 'the first flight', '', '0.072', '0.12', ''),
    ('PX4 v1.16.0 SIH', 'the first flight', '', '0.20-0.38 (its estimator wanders 0.1-0.3 m)', '', ''),
]


def main():
    rows = []
    for flavour in ('px4', 'ardupilot'):
        for label, profile in PROFILES.items():
            with tempfile.TemporaryDirectory() as tmp, running_graph(Path(tmp)) as (procs, observer):
                flight = fly_mission(procs, observer, Path(tmp), flavour, SQUARE, SPEED_MPS, profile=profile)
                m = flight.metrics
                print(f'{flavour} {label}: rmse {m["rmse_m"]:.3f} m', file=sys.stderr)
                rows.append((f'quad_vehicle_emu {flavour}', label,
                             f'{m["time_planned_s"]:.2f} / {m["time_actual_s"]:.2f}', f'{m["rmse_m"]:.3f}',
                             f'{m["max_error_m"]:.3f}', f'{m["waypoint_miss_max_m"]:.3f}'))
    print('## Bridge flight: a 3 m square at 0.8 m/s through mavlink_bridge\n')
    print(__doc__.replace('\n', ' ').strip() + ' ' + f'Control profiles over {Path(CONTROL).name}; scored window '
          'and tolerances: the vehicle\'s (10 cm, 0.1 m/s, settle 3 s).\n')
    print('| vehicle | control | time planned / actual (s) | RMSE (m) | max error (m) | waypoint miss max (m) |')
    print('|---|---|---|---|---|---|')
    for row in rows + REFERENCE:
        print('| ' + ' | '.join(row) + ' |')


if __name__ == '__main__':
    main()
