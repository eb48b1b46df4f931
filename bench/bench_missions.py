"""Every mission x controller through `quadflight fly` (the real node graph, lockstep simulator).

Default: every mission in config/missions/ except long_100 at 0.5 m/s (its flight alone takes minutes),
with pd (seed gains), pid and se3 at the seed's 0.5 m/s and at 2 m/s average, plus 2 m/s with the
drag_wind disturbance profile; plus the fast profile (config/control_fast.yaml, se3) at 2 m/s with and without
drag_wind, planned with time_allocation limits where the mission file gives trajectory.limits (the sqrt profile at
2 m/s exceeds the Crazyflie's tilt there; docs/quad_control.md "Tuning for speed").
--quick: maze only. --all: everything. Prints one markdown section.
"""

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(p) for p in sorted((ROOT / 'src').glob('quad_*'))]

from quad_bringup.running.flight import fly  # noqa: E402
from quad_bringup.running.flight_options import FlightOptions  # noqa: E402
from quad_control.position import CONTROLLERS  # noqa: E402
from quad_trajectory.mission import load_mission  # noqa: E402

SPEEDS = (0.5, 2.0)
FAST_PROFILE = ROOT / 'config' / 'control_fast.yaml'


def fast_allocation(mission) -> str | None:
    """limits where the mission file gives trajectory.limits, else the mission's own allocation."""
    return 'limits' if load_mission(mission).options.v_max_mps is not None else None


def cases(args):
    missions = sorted((ROOT / 'config' / 'missions').glob('*.yaml'))
    if args.quick:
        missions = [m for m in missions if m.stem == 'maze']
    for mission in missions:
        if args.fast_only:
            for disturbances in (None, 'drag_wind'):
                yield mission, 'se3', 2.0, disturbances, FAST_PROFILE
            continue
        for speed in SPEEDS:
            if mission.stem == 'long_100' and speed < 1.0 and not args.all:
                continue
            for controller in CONTROLLERS:
                yield mission, controller, speed, None, None
        yield mission, 'se3' if args.quick else 'pd', 2.0, 'drag_wind', None
        for disturbances in (None, 'drag_wind'):
            yield mission, 'se3', 2.0, disturbances, FAST_PROFILE


def run_case(mission, controller, speed, disturbances, profile, out_root):
    allocation = fast_allocation(mission) if profile else None
    label = f'{controller} ({profile.stem}{", " + allocation if allocation else ""})' if profile else controller
    out = out_root / f'{mission.stem}-{controller}-{speed}-{disturbances or "none"}-{profile.stem if profile else ""}'
    start = time.monotonic()
    result = fly(FlightOptions(mission=mission, controller=controller, speed_mps=speed, out=out,
                               disturbances=disturbances, control_profile=profile, time_allocation=allocation,
                               quiet=True, fly_anyway=True),  # measure what an infeasible plan does too
                 log=lambda line: None)
    wall_s = time.monotonic() - start
    m = result.metrics or {}
    return {'mission': mission.stem, 'controller': label, 'speed': speed, 'disturbances': disturbances or 'none',
            'completed': result.exit_code == 0, 'reason': result.reason.splitlines()[0] if result.exit_code else '',
            'over_s': m.get('time_over_s'), 'rmse_m': m.get('rmse_m'), 'max_m': m.get('max_error_m'),
            'actual_s': m.get('time_actual_s'), 'avg_mps': m.get('avg_velocity_mps'), 'wall_s': wall_s}


def fmt(value, spec):
    return '-' if value is None else format(value, spec)


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('--quick', action='store_true', help='the maze mission only')
    parser.add_argument('--all', action='store_true', help='also long_100 at 0.5 m/s')
    parser.add_argument('--fast-only', action='store_true', help='only the fast profile rows (2 m/s)')
    parser.add_argument('--json', type=Path, help='also write the rows as JSON')
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory(prefix='bench_missions-') as tmp:
        for case in cases(args):
            rows.append(run_case(*case, Path(tmp)))
            print(f'  {rows[-1]}', file=sys.stderr, flush=True)
    print('### Missions flown through the node graph (quadflight fly, lockstep simulator)\n')
    print('Each row is one `quadflight fly` run (separate processes, DDS, bag, report); wall time includes '
          'start-up and the report. RTF = simulated flight time / wall time. '
          f'Run: {"maze only (--quick)" if args.quick else "all missions"}'
          f'{"" if args.all else ", long_100 only at 2 m/s"}; goal at 2 m/s: RMSE < 2 cm (no disturbances), '
          '< 5 cm (drag_wind), time actual - planned < 0.3 s.\n')
    print('| mission | controller | speed (m/s) | avg flown (m/s) | disturbances | completed | actual - planned (s) '
          '| RMSE (cm) | max error (cm) | wall (s) | RTF |')
    print('|---|---|---:|---:|---|---|---:|---:|---:|---:|---:|')
    for r in rows:
        rtf = r['actual_s'] / r['wall_s'] if r['actual_s'] else None
        print(f'| {r["mission"]} | {r["controller"]} | {r["speed"]} | {fmt(r["avg_mps"], ".2f")} | '
              f'{r["disturbances"]} | '
              f'{"yes" if r["completed"] else "no: " + r["reason"][:60]} | {fmt(r["over_s"], ".3f")} | '
              f'{fmt(r["rmse_m"] and 100 * r["rmse_m"], ".2f")} | {fmt(r["max_m"] and 100 * r["max_m"], ".2f")} | '
              f'{r["wall_s"]:.1f} | {fmt(rtf, ".2f")} |')
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))


if __name__ == '__main__':
    main()
