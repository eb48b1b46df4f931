"""`quadflight plan FLEET.yaml [--out plan.json] [--speed V] [--time-allocation A]`: plan every vehicle of a fleet
mission, check the separation over time, print one line per vehicle and the fleet's minimum separation.

A conflict left after the file's deconfliction (if any) is refused: exit 2 and one line naming the pair, the time
and the distance. --out writes {"fleet", "vehicles": {name: plan JSON + start_delay_s}, "separation"}.
"""

import json
import sys

from quad_trajectory import feasibility
from quad_trajectory.fleet import fleet_from_dict, load_fleet, plan_fleet


def feasible(vehicle, plan) -> str:
    """'yes', or the worst check the plan fails on the vehicle (quad_trajectory.feasibility, as fly checks it)."""
    if vehicle is None:
        return '-'
    report = feasibility.check(plan.trajectory, vehicle)
    if report.ok:
        return 'yes'
    e = report.exceeded[0]
    return f'NO: {e.check} {e.value:.4g} {e.unit} at {e.time_s:.2f} s (limit {e.limit:.4g})'


def summary_lines(fleet_plan) -> list[str]:
    """A table: one row per vehicle (start, delay, time, length, peak speed), then the separation."""
    rows = [('vehicle', 'start (m)', 'delay (s)', 'time (s)', 'length (m)', 'max speed (m/s)', 'radius (m)',
             'feasible')]
    for v, plan, delay in zip(fleet_plan.fleet.vehicles, fleet_plan.plans, fleet_plan.delays_s):
        s = plan.summary()
        start = ', '.join(f'{c:.2f}' for c in v.mission.initial_position)
        rows.append((v.name, f'({start})', f'{delay:g}', f'{s["time_planned_s"]:.3f}', f'{s["length_planned_m"]:.3f}',
                     f'{s["max_speed_mps"]:.3f}', f'{v.radius_m:g}', feasible(v.mission.vehicle, plan)))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = ['  '.join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows]
    report = fleet_plan.report
    for change in fleet_plan.changes:
        lines.append(f'deconflicted: {change}')
    closest = report.closest
    if closest:
        a, b, d, t = closest
        req = report.required_m[report.names.index(a), report.names.index(b)]
        lines.append(f'minimum separation: {d:.3f} m ({a} and {b} at t = {t:.2f} s; required {req:.3f} m; '
                     f'checked every {report.step_s * 1000:.1f} ms over {report.horizon_s:.2f} s)')
    return lines


def run(args, data: dict | None = None) -> int:
    """The plan command on a fleet file (`data`: its parsed content, when plan has read it already)."""
    if args.csv is not None:
        print('quadflight plan: --csv is for one vehicle; a fleet plan writes --out only', file=sys.stderr)
        return 2
    try:
        fleet = fleet_from_dict(data, str(args.mission)) if data is not None else load_fleet(args.mission)
        overrides = {'time_allocation': args.time_allocation} if args.time_allocation else {}
        result = plan_fleet(fleet, speed_mps=args.speed, **overrides)
    except ValueError as exc:
        print(f'quadflight plan: {exc}', file=sys.stderr)
        return 2
    for v, plan in zip(fleet.vehicles, result.plans):
        for m in plan.merged:
            print(f'note: {v.name}: {m}')
    print('\n'.join(summary_lines(result)))
    refusal = result.refusal()
    if refusal:
        print(f'quadflight plan: {refusal}', file=sys.stderr)
        return 2
    if args.out is not None:
        report = result.report
        closest = report.closest
        content = {'fleet': fleet.name, 'mission': str(args.mission),
                   'vehicles': {v.name: {**json.loads(p.to_json()), 'start_delay_s': d}
                                for v, p, d in zip(fleet.vehicles, result.plans, result.delays_s)},
                   'separation': {'minimum_m': closest[2] if closest else None,
                                  'pair': list(closest[:2]) if closest else None,
                                  'time_s': closest[3] if closest else None, 'step_s': report.step_s,
                                  'deconflicted': result.changes}}
        try:
            args.out.parent.mkdir(parents=True, exist_ok=True)
            args.out.write_text(json.dumps(content))
        except OSError as exc:
            print(f'quadflight plan: --out {args.out}: cannot write it ({exc.strerror or exc})', file=sys.stderr)
            return 2
        print(f'wrote {args.out}')
    return 0
