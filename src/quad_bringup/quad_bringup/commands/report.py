"""`quadflight report BAG [--out DIR]`: metrics.json, report.md and figures/ from a rosbag2 bag."""

import json
import shutil
import sys
from pathlib import Path

from quad_common.paths import input_path


def add_arguments(parser):
    parser.add_argument('bag', help='rosbag2 bag directory (MCAP or sqlite3; a killed recorder\'s bag is read from a '
                                    'repaired copy, BAG.repaired, never changed in place)')
    parser.add_argument('--out', help='output directory (default: the run directory for runs/NAME/bag, '
                                      'else BAG_report next to the bag)')
    parser.add_argument('--vehicle', type=input_path,
                        help="vehicle YAML whose completion: gives the tolerances and settle time (e.g. "
                             "config/vehicles/px4_quad.yaml for a real flight)")
    add_completion_arguments(parser)


def add_completion_arguments(parser):
    """The completion rule's options (report and fly): each overrides the vehicle's `completion:`."""
    from quad_bringup.analysis.completion import Completion

    d = Completion()
    parser.add_argument('--position-tolerance', type=float, metavar='M',
                        help=f"completion: distance to the final waypoint (default: the vehicle's, else "
                             f"{d.position_tolerance_m} m)")
    parser.add_argument('--speed-tolerance', type=float, metavar='V',
                        help=f"completion: speed (default: the vehicle's, else {d.speed_tolerance_mps} m/s)")
    parser.add_argument('--settle', type=float, metavar='S',
                        help=f"without completion the scored window ends S s after the plan's end (default: the "
                             f"vehicle's, else {d.settle_s} s)")


def completion_overrides(args) -> dict:
    return {'position_tolerance_m': args.position_tolerance, 'speed_tolerance_mps': args.speed_tolerance,
            'settle_s': args.settle}


def default_out(bag: Path) -> Path:
    bag = bag.resolve()
    return bag.parent if bag.name == 'bag' else bag.with_name(bag.name + '_report')


def run(args) -> int:
    from quad_bringup.analysis.completion import Completion

    bag = Path(args.bag)
    out = Path(args.out) if args.out else default_out(bag)
    try:
        vehicle = None
        if args.vehicle:   # its fields checked in pure Python first: quad_common.vehicle imports numpy
            from quad_common.vehicle_file import load_vehicle_fields

            load_vehicle_fields(args.vehicle)
            from quad_common.vehicle import load_vehicle

            vehicle = load_vehicle(args.vehicle)
        rule = Completion.for_vehicle(vehicle, **completion_overrides(args))
    except ValueError as exc:
        print(f'quadflight report: {exc}', file=sys.stderr)
        return 2
    if bag.is_dir():   # the bag's readers (rosbags, numpy) only for a bag that is there
        from quad_bringup.analysis.report import truncation_summary
        from quad_bringup.recording.recorder import needs_repair, repaired_copy

        if needs_repair(bag):  # said first: it holds even if the bag then proves unusable
            try:
                print(truncation_summary(repaired_copy(bag).as_dict()), flush=True)
            except (OSError, ValueError) as exc:
                print(f'quadflight report: {exc}', file=sys.stderr)
                return 2
    if not bag.exists():
        print(f'quadflight report: {bag}: no such directory', file=sys.stderr)
        return 2
    extra = {}
    if (out / 'metrics.json').exists():  # keep what fly recorded about the run (mission, controller, outcome)
        keep = ('mission', 'controller', 'speed_mps', 'outcome')
        try:
            recorded = json.loads((out / 'metrics.json').read_text())
            if not isinstance(recorded, dict):
                raise ValueError(f'a JSON {type(recorded).__name__}, not an object')
        except (OSError, ValueError) as exc:   # JSONDecodeError and UnicodeDecodeError are ValueErrors
            print(f'quadflight report: --out {out}: its metrics.json is not one report wrote ({str(exc)[:120]}): '
                  'move it or choose another --out', file=sys.stderr)
            return 2
        extra = {k: v for k, v in recorded.items() if k in keep}
    created = not out.exists()
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        print(f'quadflight report: --out {out}: cannot create it ({exc.strerror or exc})', file=sys.stderr)
        return 2
    from rosbags.rosbag2 import ReaderError

    from quad_bringup.analysis.report import metrics_table, write_report
    from quad_bringup.analysis.report_figures import PARTS

    try:   # the figures on every core: this process has no threads of its own to make a fork unsafe
        metrics = write_report(bag, out, extra, rule, figure_parts=PARTS)
    except (OSError, ValueError, ReaderError, StopIteration) as exc:
        if created:   # a refusal leaves nothing behind
            shutil.rmtree(out, ignore_errors=True)
        why = str(exc) or 'none of the flight topics (odom, trajectory, cmd/attitude_thrust) in it'
        print(f'quadflight report: {bag}: {why}', file=sys.stderr)
        return 2
    print(metrics_table(metrics))
    print(f'report: {out / "report.md"}, metrics: {out / "metrics.json"}, figures: {out / "figures"}')
    return 0
