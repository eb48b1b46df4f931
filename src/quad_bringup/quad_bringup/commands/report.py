"""`quadflight report BAG [--out DIR]`: metrics.json, report.md and figures/ from a rosbag2 bag."""

import json
import sys
from pathlib import Path

from rosbags.rosbag2 import ReaderError

from quad_bringup.recorder import needs_repair, repaired_copy
from quad_bringup.report import Completion, metrics_table, truncation_summary, write_report


def add_arguments(parser):
    parser.add_argument('bag', help='rosbag2 bag directory (MCAP or sqlite3; a killed recorder\'s bag is read from a '
                                    'repaired copy, BAG.repaired, never changed in place)')
    parser.add_argument('--out', help='output directory (default: the run directory for runs/NAME/bag, '
                                      'else BAG_report next to the bag)')
    parser.add_argument('--position-tolerance', type=float, default=Completion.position_tolerance_m, metavar='M',
                        help='completion: distance to the final waypoint (default %(default)s m)')
    parser.add_argument('--speed-tolerance', type=float, default=Completion.speed_tolerance_mps, metavar='V',
                        help='completion: speed (default %(default)s m/s)')


def default_out(bag: Path) -> Path:
    bag = bag.resolve()
    return bag.parent if bag.name == 'bag' else bag.with_name(bag.name + '_report')


def run(args) -> int:
    bag = Path(args.bag)
    out = Path(args.out) if args.out else default_out(bag)
    for name, value in (('--position-tolerance', args.position_tolerance), ('--speed-tolerance', args.speed_tolerance)):
        if not value > 0:
            print(f'quadflight report: {name} = {value} refused: must be > 0', file=sys.stderr)
            return 2
    if bag.is_dir() and needs_repair(bag):  # said first: it holds even if the bag then proves unusable
        try:
            print(truncation_summary(repaired_copy(bag).as_dict()), flush=True)
        except (OSError, ValueError) as exc:
            print(f'quadflight report: {exc}', file=sys.stderr)
            return 2
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        print(f'quadflight report: --out {out}: cannot create it ({exc.strerror or exc})', file=sys.stderr)
        return 2
    extra = {}
    if (out / 'metrics.json').exists():  # keep what fly recorded about the run (mission, controller, outcome)
        keep = ('mission', 'controller', 'speed_mps', 'outcome')
        extra = {k: v for k, v in json.loads((out / 'metrics.json').read_text()).items() if k in keep}
    try:
        metrics = write_report(bag, out, extra, Completion(args.position_tolerance, args.speed_tolerance))
    except (OSError, ValueError, ReaderError) as exc:
        print(f'quadflight report: {exc}', file=sys.stderr)
        return 2
    print(metrics_table(metrics))
    print(f'report: {out / "report.md"}, metrics: {out / "metrics.json"}, figures: {out / "figures"}')
    return 0
