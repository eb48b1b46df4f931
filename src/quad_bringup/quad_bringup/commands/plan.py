"""`quadflight plan MISSION.yaml --out traj.json [--csv RATE] [--speed V] [--time-allocation A]`: plan only, no flight.
A fleet mission (a `vehicles:` list) is planned by quad_bringup.commands.fleet_plan.

The JSON is docs/design.md's plan layout ({"waypoints", "segments": [{"duration", "coefficients": {x, y, z, yaw}}]},
coefficients in ascending powers of local time) plus the plan's options, merges and summary.
"""

import os
import sys
from pathlib import Path

from quad_common.paths import input_path
from quad_trajectory.timing import ALLOCATIONS


def add_time_allocation_argument(parser):
    """--time-allocation, the same option for plan and fly."""
    parser.add_argument('--time-allocation', choices=ALLOCATIONS,
                        help="segment times (overrides the mission's): sqrt (the seed's), proportional, limits "
                             '(within trajectory.limits), optimal (min snap for the total time), fastest (as fast as '
                             "the vehicle's limits less trajectory.margin allow)")


def add_arguments(parser):
    parser.add_argument('mission', type=input_path, help='mission YAML, e.g. config/missions/maze.yaml')
    parser.add_argument('--out', type=Path, help='write the trajectory JSON here')
    parser.add_argument('--csv', type=float, metavar='RATE',
                        help='also write samples at RATE Hz next to --out (.csv): t, position, velocity, acceleration')
    parser.add_argument('--speed', type=float, metavar='V', help='average speed in m/s (overrides the mission)')
    add_time_allocation_argument(parser)


def write_csv(path: Path, trajectory, rate_hz: float):
    import numpy as np

    t = trajectory.sample_times(rate_hz)
    columns = [t[:, None]] + [trajectory.evaluate(t, order) for order in range(3)]
    header = 't_s,' + ','.join(f'{q}_{a}' for q in ('pos', 'vel', 'acc') for a in ('x', 'y', 'z', 'yaw'))
    np.savetxt(path, np.hstack(columns), delimiter=',', header=header, comments='', fmt='%.9g')


def summary_table(result) -> str:
    s = result.summary()
    rows = [('segments', f'{s["segments"]}'), ('waypoints', f'{s["waypoints"]} ({s["merged_waypoints"]} merged)'),
            ('time planned (s)', f'{s["time_planned_s"]:.3f}'), ('length planned (m)', f'{s["length_planned_m"]:.3f}'),
            ('max speed (m/s)', f'{s["max_speed_mps"]:.3f}'),
            ('max acceleration (m/s^2)', f'{s["max_acceleration_mps2"]:.3f}')]
    width = max(len(k) for k, _ in rows)
    return '\n'.join(f'{k:<{width}}  {v}' for k, v in rows)


def refuse_overwriting_inputs(outputs, inputs) -> str | None:
    """Inputs are never modified: the refusal when an output path is one of the inputs."""
    from quad_bringup.checks.inputs import same_file
    for name, out in outputs:
        for what, path in inputs:
            if out is not None and path is not None and same_file(out, path):
                return f'{name} {out} refused: it is the {what}, an input (never modified): choose another path'
    return None


def run(args) -> int:
    from quad_bringup.limits import csv_refusal, refusal
    from quad_common.yaml_io import load_yaml
    from quad_trajectory.mission_kind import is_fleet

    if args.csv is not None and args.out is None:
        print('quadflight plan: --csv needs --out (the CSV goes next to it)', file=sys.stderr)
        return 2
    csv_path = args.out.with_suffix('.csv') if args.csv is not None else None
    reason = refusal('speed_mps', args.speed) or refusal('csv_rate_hz', args.csv) or refuse_overwriting_inputs(
        [('--out', args.out), ('--csv (next to --out)', csv_path)], [('mission', args.mission)])
    if not reason and not args.mission.is_file():
        reason = f'mission {args.mission}: ' + ('a directory, not a mission file' if args.mission.is_dir() else
                                                'no such file')
    if reason:
        print(f'quadflight plan: {reason}', file=sys.stderr)
        return 2
    try:
        data = load_yaml(os.fspath(args.mission))   # read once: a fleet or one vehicle's mission
        if is_fleet(data):   # a `vehicles:` list: docs/missions.md "Fleets"
            from quad_bringup.commands import fleet_plan
            return fleet_plan.run(args, data)
        from quad_trajectory.mission_file import mission_fields

        fields = mission_fields(data, os.fspath(args.mission))   # refused before numpy is imported
        from quad_trajectory.mission import mission_from_dict, plan_mission, preflight
        from quad_trajectory.planner import allocation_lines

        mission = mission_from_dict(data, os.fspath(args.mission), fields)
        reason = refuse_overwriting_inputs([('--out', args.out), ('--csv (next to --out)', csv_path)],
                                           [('mission\'s vehicle file', mission.vehicle_path),
                                            ('mission\'s world file', mission.world_path)])
        if reason:
            raise ValueError(reason)
        overrides = {'time_allocation': args.time_allocation} if args.time_allocation else {}
        result = plan_mission(mission, speed_mps=args.speed, **overrides)
        if args.csv is not None:
            reason = csv_refusal(args.csv, result.trajectory.duration_s)   # before anything is written
            if reason:
                raise ValueError(reason)
    except ValueError as exc:
        print(f'quadflight plan: {exc}', file=sys.stderr)
        return 2
    for m in result.merged:
        print(f'note: {m}')
    if result.inserted_points:
        print(f'note: {result.inserted_points} points inserted to avoid obstacles')
    print(summary_table(result))
    for line in allocation_lines(result, mission.vehicle):
        print(line)
    if mission.vehicle is not None:   # the plan is written either way; fly refuses what fails here
        print('\n'.join(preflight(mission, result, speed_mps=args.speed).lines()))
    if args.out is not None:
        outputs = [('--out', args.out, lambda path: path.write_text(result.to_json(mission=str(args.mission))))]
        if args.csv is not None:
            outputs.append(('--csv', csv_path, lambda path: write_csv(path, result.trajectory, args.csv)))
        try:
            args.out.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            print(f'quadflight plan: --out {args.out}: cannot write it ({exc.strerror or exc})', file=sys.stderr)
            return 2
        if (problem := write_all_or_nothing(outputs)) is not None:
            print(f'quadflight plan: {problem}', file=sys.stderr)
            return 2
        for _, path, _ in outputs:
            print(f'wrote {path}')
    return 0


def write_all_or_nothing(outputs) -> str | None:
    """Writes each (option, path, write(path)) to a temporary file beside its path, then renames them all into
    place: a full disk or any OSError leaves no partial file and no half of the set (the temporary files are
    removed). Returns the error line naming the option and the path, or None."""
    import tempfile

    written, current = [], outputs[0]
    try:
        for current in outputs:
            fd, temporary = tempfile.mkstemp(prefix=f'.{current[1].name}.', dir=current[1].parent)
            os.close(fd)
            written.append(Path(temporary))
            current[2](Path(temporary))
        for current, temporary in zip(outputs, written):
            os.replace(temporary, current[1])
        return None
    except OSError as exc:
        return f'{current[0]} {current[1]}: cannot write it ({exc.strerror or exc}); nothing written'
    finally:
        for temporary in written:
            temporary.unlink(missing_ok=True)
