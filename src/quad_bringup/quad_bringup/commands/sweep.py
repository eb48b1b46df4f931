"""`quadflight sweep SPEC.yaml`: many flights (offline loop or, with --graph, the ROS graph), one table."""

import sys
from pathlib import Path

from quad_common.paths import input_path


def add_arguments(parser):
    parser.add_argument('spec', type=input_path, help='sweep spec YAML (missions, controllers, vehicles, disturbances, '
                                                'seeds; docs/quad_bringup.md "Many flights")')
    parser.add_argument('--out', type=Path, help='output directory (default runs/sweep-SPEC); rerunning with the '
                                                 'same one resumes: runs already in its table are skipped')
    parser.add_argument('--graph', action='store_true',
                        help='fly each run through the ROS graph (`fly`, its own ROS domain) instead of the '
                             'offline loop')
    add_execution_arguments(parser)
    parser.add_argument('--no-figures', action='store_true', help='table and summary only')


def add_execution_arguments(parser):
    parser.add_argument('--scheduler', metavar='ADDRESS',
                        help='run on a Dask distributed cluster (e.g. tcp://10.0.0.1:8786) instead of the local '
                             'process pool')
    parser.add_argument('--workers', type=int, metavar='N', help='local pool size (default: all cores)')


def run(args) -> int:
    from quad_bringup.experiments.runs import SpecError
    from quad_bringup.experiments.sweep import run_sweep, summary_markdown

    out = args.out or Path('runs') / f'sweep-{args.spec.stem}'
    try:
        rows, summary = run_sweep(args.spec, out, mode='graph' if args.graph else 'offline',
                                  scheduler=args.scheduler, workers=args.workers, figures=not args.no_figures,
                                  log=lambda line: print(line, file=sys.stderr, flush=True))
    except (SpecError, RuntimeError) as exc:
        print(f'sweep refused: {exc}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f'\nsweep interrupted: the finished runs are in {out}/runs.csv; rerun the same command to resume',
              file=sys.stderr)
        return 130
    print(summary_markdown(summary))
    failed = sum(bool(r['failed']) for r in rows)
    print(f'{len(rows)} runs, {failed} failed: {out}/runs.csv, summary.md, figures/')
    return 0
