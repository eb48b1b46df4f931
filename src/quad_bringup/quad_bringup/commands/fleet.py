"""`quadflight fleet FLEET.yaml [--out DIR] [--graph [--process-per-node]]`: plan a fleet mission, check its
separation, and fly every vehicle: offline (quad_bringup.offline.fleet_loop: each vehicle's control loop against its own
simulator, in lockstep; no ROS), or with --graph through the ROS graph (quad_bringup.running.fleet_graph: one sim_node
for the fleet under one /clock, each vehicle's nodes under its namespace, a rosbag2 bag of every vehicle).

Refused (exit 2, one line) before flight: a separation conflict left after the file's deconfliction, or a plan that
fails fly's feasibility check on its vehicle, unless --fly-anyway. The verdict: exit 0 when every vehicle completed
without a collision, else 1. --out DIR writes fleet.json (each vehicle's metrics, the collisions, the separation)
and fleet.png (the paths from above and the fleet's minimum separation over time).
"""

import json
import os
import sys
from pathlib import Path

from quad_bringup.commands.plan import add_time_allocation_argument
from quad_common.paths import input_path


def add_arguments(parser):
    parser.add_argument('mission', type=input_path,
                        help='fleet mission YAML, e.g. config/missions/fleets/formation4.yaml')
    parser.add_argument('--out', type=Path, help='write fleet.json and fleet.png here')
    parser.add_argument('--speed', type=float, metavar='V', help='average speed in m/s (overrides the mission)')
    add_time_allocation_argument(parser)
    parser.add_argument('--disturbances', default='none', metavar='PROFILE',
                        help='simulator disturbance profile for every vehicle (config/disturbances.yaml)')
    parser.add_argument('--graph', action='store_true',
                        help='fly through the ROS graph (sim_node, trajectory_node and position_controller per '
                             'vehicle, the recorder): a bag and the verdict from it; --out defaults to runs/')
    parser.add_argument('--process-per-node', action='store_true',
                        help='--graph: every node its own process (as launch_ros starts them) instead of one process '
                             'for the vehicles\' nodes')
    parser.add_argument('--no-figures', action='store_true',
                        help='--graph: each vehicle\'s report without its figures (faster for a large fleet)')
    parser.add_argument('--fly-anyway', action='store_true',
                        help='fly a separation conflict or an infeasible plan instead of refusing it')


def verdict_lines(run) -> list[str]:
    rows = [('vehicle', 'completed', 'rmse (cm)', 'max error (cm)', 'time (s)', 'collided')]
    for name in run.names:
        m = run.metrics[name]
        rows.append((name, 'yes' if m['completed'] else 'NO' + (f' ({m["stopped"]})' if m.get('stopped') else ''),
                     f'{100 * m["rmse_m"]:.2f}', f'{100 * m["max_error_m"]:.2f}', f'{m["time_actual_s"]:.2f}',
                     'YES' if m['collided'] else 'no'))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = ['  '.join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows]
    if len(run.names) > 1:
        d, t = run.closest()
        lines.append(f'flown minimum separation: {d:.3f} m at t = {t:.2f} s')
    for t, a, b, d in run.collisions:
        lines.append(f'COLLISION: {a} and {b} at t = {t:.2f} s ({d:.3f} m apart)')
    lines.append(f'simulated {run.sim_s:.2f} s in {run.wall_s["total"]:.2f} s ({run.real_time_factor:.1f}x real time)')
    return lines


def write_figure(run, path):
    import numpy as np

    """The flown paths from above (planned dashed, collisions marked) and the minimum separation over time."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, (top, sep) = plt.subplots(1, 2, figsize=(13, 5.5))
    for k, name in enumerate(run.names):
        color = f'C{k % 10}'
        plan, delay = run.plan.plans[k], run.plan.delays_s[k]
        planned = plan.trajectory.evaluate(run.t_s - delay)[:, :3]
        top.plot(planned[:, 0], planned[:, 1], '--', color=color, linewidth=1)
        p = run.positions[name]
        top.plot(p[:, 0], p[:, 1], color=color, linewidth=1.5, label=name)
        top.plot(p[0, 0], p[0, 1], 'o', color=color)
    for t, a, _b, _ in run.collisions:
        k = int(np.argmin(np.abs(run.t_s - t)))
        top.plot(*run.positions[a][k, :2], 'kx', markersize=12, markeredgewidth=2)
    top.set(xlabel='x (m)', ylabel='y (m)', title=f'{run.plan.fleet.name}: flown (solid), planned (dashed)')
    top.axis('equal')
    top.legend(loc='best', fontsize=8)
    required = run.plan.report.required_m
    sep.plot(run.t_s, run.min_separation_m, label='flown (closest pair)')
    if len(run.names) > 1:
        sep.axhline(float(required[np.triu_indices(len(run.names), 1)].min()), color='tab:red', linestyle=':',
                    label='minimum separation')
        radii = np.array([v.radius_m for v in run.plan.fleet.vehicles])
        sep.axhline(float(np.sort(radii)[:2].sum()), color='black', linestyle='-', linewidth=0.8,
                    label='contact (two radii)')
    sep.set(xlabel='t (s)', ylabel='distance (m)', title='fleet minimum separation', ylim=(0, None))
    sep.legend(loc='best')
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run(args) -> int:
    from quad_bringup.running.flight import EXIT_COMPLETED, EXIT_FAILED, EXIT_REFUSED
    from quad_common.yaml_io import load_yaml
    from quad_trajectory.mission_kind import check_fleet_keys
    try:
        data = load_yaml(os.fspath(args.mission))   # a file that is not there: said before the planner is imported
        check_fleet_keys(data, os.fspath(args.mission))   # as is a one-vehicle mission
        from quad_trajectory.fleet import fleet_from_dict, plan_fleet

        fleet = fleet_from_dict(data, os.fspath(args.mission))   # before the simulator and the loop are imported
        import numpy as np

        from quad_bringup.commands.fleet_plan import feasible, summary_lines
        from quad_bringup.offline.closed_loop import LoopOptions
        from quad_bringup.offline.fleet_loop import fly_fleet

        overrides = {'time_allocation': args.time_allocation} if args.time_allocation else {}
        plan = plan_fleet(fleet, speed_mps=args.speed, **overrides)
        print('\n'.join(summary_lines(plan)))
        reasons = [plan.refusal()] if plan.refusal() else []
        reasons += [f'{v.name}: plan not feasible: {f}' for v, p in zip(fleet.vehicles, plan.plans)
                    if (f := feasible(v.mission.vehicle, p)).startswith('NO')]
        if reasons and not args.fly_anyway:
            print(f'quadflight fleet: {reasons[0]} (--fly-anyway flies it)', file=sys.stderr)
            return EXIT_REFUSED
        if args.graph:
            from quad_bringup.running.fleet_graph import default_out_dir, fly_graph

            if args.disturbances != 'none':
                raise ValueError('--disturbances is offline only (sim_node takes its profile from sim.yaml)')
            args.out = args.out or default_out_dir(fleet.name)
            result, timing = fly_graph(plan, args.out, speed_mps=args.speed, hosted=not args.process_per_node,
                                       reports=True, figures=not args.no_figures)
            result.wall_s['total'] = timing.flight_s
            result.wall_s['command'] = timing.total_s
        else:
            result = fly_fleet(fleet, LoopOptions(speed_mps=args.speed, plan_overrides=overrides or None,
                                                  disturbances=args.disturbances), fleet_plan=plan,
                               refuse_conflicts=False)
    except RuntimeError as exc:
        print(f'quadflight fleet: {exc}', file=sys.stderr)
        return EXIT_FAILED
    except ValueError as exc:
        print(f'quadflight fleet: {exc}', file=sys.stderr)
        return EXIT_REFUSED
    print('\n'.join(verdict_lines(result)), flush=True)
    drawing = _start(result.finish)   # the vehicles' figures on the pool while this process draws fleet.png
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        d, t = result.closest()
        content = {'fleet': fleet.name, 'mission': str(args.mission), 'metrics': result.metrics,
                   'collisions': [dict(zip(('time_s', 'a', 'b', 'distance_m'), c)) for c in result.collisions],
                   'flown_minimum_separation': {'distance_m': d if np.isfinite(d) else None, 'time_s': t},
                   'start_delays_s': dict(zip(result.names, plan.delays_s)), 'deconflicted': plan.changes,
                   'wall_s': result.wall_s, 'simulated_s': result.sim_s}
        (args.out / 'fleet.json').write_text(json.dumps(content, indent=1, default=float))
        write_figure(result, args.out / 'fleet.png')
        print(f'wrote {args.out / "fleet.json"}, {args.out / "fleet.png"}', flush=True)
    if (problem := drawing()) is not None:
        print(f'quadflight fleet: {problem}', file=sys.stderr)
        return EXIT_FAILED
    if result.finish is not None:
        print(f'wrote each vehicle\'s report and figures under {args.out / "vehicles"}')
    ok = all(m['completed'] and not m['collided'] for m in result.metrics.values())
    return EXIT_COMPLETED if ok else EXIT_FAILED


def _start(draw):
    """draw() on a thread of its own (it waits on a process pool); returns a join -> its error's text or None."""
    if draw is None:
        return lambda: None
    import threading

    error = []

    def target():
        try:
            draw()
        except Exception as exc:   # RuntimeError: a report whose figures failed (fleet_graph.draw_reports_figures)
            error.append(str(exc) or repr(exc))

    thread = threading.Thread(target=target, name='vehicle-figures')
    thread.start()

    def join():
        thread.join()
        return error[0] if error else None
    return join
