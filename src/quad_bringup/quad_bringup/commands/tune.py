"""`quadflight tune SPEC.yaml`: robust gain search over missions x plant family, then a check through the graph."""

import json
import sys
from pathlib import Path

from quad_bringup.commands.sweep import add_execution_arguments
from quad_common.paths import input_path


def add_arguments(parser):
    parser.add_argument('spec', type=input_path, help='tune spec YAML (controller, parameters with bounds, missions, '
                                                'vehicles, disturbances, cost, optimizer)')
    parser.add_argument('--out', type=Path, help='output directory (default runs/tune-SPEC); profile.yaml, '
                                                 'cost.json, evaluations.csv, runs.csv, verify.md')
    parser.add_argument('--no-verify', action='store_true',
                        help='skip flying the best profile through the ROS graph')
    add_execution_arguments(parser)


def run(args) -> int:
    from quad_bringup.experiments.runs import SpecError
    from quad_bringup.experiments.tune import run_tune

    out = args.out or Path('runs') / f'tune-{args.spec.stem}'
    try:
        summary = run_tune(args.spec, out, scheduler=args.scheduler, workers=args.workers,
                           verify=False if args.no_verify else None,
                           log=lambda line: print(line, file=sys.stderr, flush=True))
    except (SpecError, RuntimeError) as exc:
        print(f'tune refused: {exc}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f'\ntune interrupted: finished runs are in {out}/runs.csv; rerunning reuses them', file=sys.stderr)
        return 130
    print(f'{summary["aggregate"]} cost: {summary["cost_before_m"]:.4f} m (start) -> '
          f'{summary["cost_after_m"]:.4f} m (best) after {summary["evaluations"]} evaluations '
          f'({summary["runs"]} runs)')
    print('best gains: ' + json.dumps({k: v for k, v in summary['best_gains'].items()
                                       if summary['base_gains'].get(k) != v}))
    if 'verify' in summary:
        print((out / 'verify.md').read_text())
    print(f'profile: {out}/profile.yaml (cost.json, evaluations.csv, runs.csv beside it)')
    return verification_code(summary.get('verify', []))


def verification_code(report: list[dict]) -> int:
    """1 (said on stderr) when a graph flight of the verification failed or never flew, else 0."""
    failed = [r for r in report if not r['graph_completed']]
    if not failed:
        return 0
    why = str(failed[0]['graph_failure'] or 'no verdict').splitlines()[0][:300]
    print(f'tune: the verification through the ROS graph failed on {len(failed)} of {len(report)} missions '
          f'({failed[0]["mission"]}: {why}); profile.yaml is written, unverified', file=sys.stderr)
    return 1
