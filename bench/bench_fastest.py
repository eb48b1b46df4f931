"""time_allocation fastest: how near the shortest feasible plan it gets, how long it takes, and how it flies.

1. Planned total time of every mission with the seed's sqrt profile at the mission's speed, `limits`, the sqrt
   shape scaled uniformly to the margined limits, `fastest`, and an independent brute-force reference: scipy's
   SLSQP over all segment times (log T) with every (check, sample) of feasibility.py as a constraint, from
   several starts (the sqrt and proportional shapes and random shapes, each scaled to the limits by the
   reference's own bisection), plus differential evolution over the shape (each candidate scaled to the limits)
   for missions of up to DE_MAX_SEGMENTS segments; the best of all is the reference. The reference shares only
   the problem's definition with fastest.py (feasibility.needs_from_derivatives and margined_limits: the checks
   `plan` and `fly` run) and the solver; its optimiser, its scaling and its starts are its own.
2. Compute time of the allocation alone for 10, 100 and 1000 segments (bench_plan's survey missions), CPU
   seconds of this process, median of RUNS.
3. Every mission flown with fastest in the offline loop (quad_bringup.offline.closed_loop: the graph's simulator and
   control loop without ROS) with the default se3 profile on the nominal Crazyflie and every plant family
   member, and through the ROS graph (`quadflight fly`) on GRAPH_MISSIONS.
Prints one markdown section. --quick: fewer missions in the reference and no graph flights.
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(p) for p in sorted((ROOT / 'src').glob('quad_*'))]

from quad_bringup.offline.closed_loop import LoopOptions, fly_offline, load_control_profile  # noqa: E402
from quad_common.paths import resolve_config  # noqa: E402
from quad_common.vehicle import load_vehicle  # noqa: E402
from quad_common.vehicle_file import load_plant_family  # noqa: E402
from quad_trajectory import fastest, feasibility, planner, solver, timing  # noqa: E402
from quad_trajectory.mission import load_mission, plan_mission  # noqa: E402
from quad_trajectory.polynomial import PiecewisePolynomial  # noqa: E402
from quad_trajectory.survey import survey_waypoints  # noqa: E402

MARGIN = fastest.DEFAULT_MARGIN
REFERENCE_MAX_SEGMENTS = 30
DE_MAX_SEGMENTS = 4
RANDOM_STARTS = 3
RUNS = 3
SIZES = (10, 100, 1000)
GRAPH_MISSIONS = ('maze', 'slalom_dense')
SE3_PROFILE = 'config/control_se3.yaml'


class Reference:
    """min sum T s.t. every (check, sample) of feasibility.py within the margined limits: SLSQP + DE."""

    def __init__(self, points, options, vehicle):
        self.points, self.vehicle = points, vehicle
        self.system = solver.System(len(points) - 1, solver.ORDERS[options.method], options.waypoint_constraint)
        self.limits = feasibility.margined_limits(vehicle, MARGIN)
        self.s = np.linspace(0.0, 1.0, feasibility.SAMPLES_PER_SEGMENT)
        self.scale_of = {name: (lim if upper else vehicle.thrust_max_n)
                         for name, (lim, _, upper) in self.limits.items()}

    def derivatives(self, T):
        traj = PiecewisePolynomial(T, self.system.solve(T, self.points, banded=True))
        return feasibility.derivatives(traj, slice(None), self.s)

    def slack(self, a, j, snap):
        """Per (check, segment, sample): >= 0 inside the limits (each normalised by its limit)."""
        needs = feasibility.needs_from_derivatives(a, j, snap, self.vehicle)
        return np.stack([(lim - needs[k]) / self.scale_of[k] if upper else (needs[k] - lim) / self.scale_of[k]
                         for k, (lim, _, upper) in self.limits.items()])

    def scaled(self, T):
        """T times the smallest k (bisection, 60 halvings of log k) with every sample inside the limits."""
        a, j, snap = self.derivatives(T)
        lo, hi = np.log(1e-3), np.log(1e3)
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            k = np.exp(mid)
            if self.slack(a / k ** 2, j / k ** 3, snap / k ** 4).min() >= 0:
                hi = mid
            else:
                lo = mid
        return T * np.exp(hi)

    def slsqp(self, T0):
        from scipy.optimize import minimize

        x0 = np.log(T0)
        res = minimize(lambda x: np.exp(x).sum(), x0, jac=lambda x: np.exp(x), method='SLSQP',
                       bounds=[(v - 2.0, v + 2.0) for v in x0],
                       constraints=[{'type': 'ineq',
                                     'fun': lambda x: self.slack(*self.derivatives(np.exp(x))).ravel()}],
                       options={'maxiter': 300, 'ftol': 1e-10})
        T = np.exp(res.x)
        return self.scaled(T)   # the last iterate, made exactly feasible (a hair of scale at most)

    def differential_evolution(self, seed):
        from scipy.optimize import differential_evolution

        m = len(self.points) - 1
        base = timing.sqrt_allocation(self.points, 1.0)
        res = differential_evolution(lambda y: self.scaled(base * np.exp(np.r_[0.0, y])).sum(),
                                     [(-1.5, 1.5)] * (m - 1), seed=seed, maxiter=60, popsize=12, tol=1e-8,
                                     polish=False)
        return self.scaled(base * np.exp(np.r_[0.0, res.x]))

    def best(self, seed=0):
        rng = np.random.default_rng(seed)
        sqrt, prop = timing.sqrt_allocation(self.points, 1.0), timing.proportional_allocation(self.points, 1.0)
        starts = [sqrt, prop] + [sqrt * np.exp(rng.normal(0.0, 0.3, sqrt.size)) for _ in range(RANDOM_STARTS)]
        found = [self.slsqp(self.scaled(T)) for T in starts]
        if len(self.points) - 1 <= DE_MAX_SEGMENTS:
            found.append(self.slsqp(self.differential_evolution(seed)))
        return min(found, key=np.sum), len(found)


def mission_rows(names, reference_max):
    rows = []
    for name in names:
        mission = load_mission(resolve_config(f'config/missions/{name}.yaml'))
        vehicle = mission.vehicle
        sqrt = plan_mission(mission)
        limits = plan_mission(mission, time_allocation='limits')
        t0 = time.process_time()
        fast = plan_mission(mission, time_allocation='fastest')
        plan_cpu = time.process_time() - t0
        points = fast.points
        ref = Reference(points, fast.options, vehicle)
        uniform = ref.scaled(timing.sqrt_allocation(points, 1.0)).sum()
        t0 = time.process_time()
        ours = fastest.fastest_times(points, vehicle, fast.options.method, fast.options.waypoint_constraint, MARGIN)
        ours_cpu = time.process_time() - t0
        row = {'mission': name, 'segments': len(points) - 1, 'inserted': fast.inserted_points,
               'speed': mission.options.speed_mps, 'sqrt_s': sqrt.trajectory.duration_s,
               'sqrt_ok': feasibility.check(sqrt.trajectory, vehicle).ok, 'limits_s': limits.trajectory.duration_s,
               'uniform_s': uniform, 'fastest_s': fast.trajectory.duration_s, 'fastest_cpu_s': ours_cpu,
               'plan_cpu_s': plan_cpu, 'ok': feasibility.check(fast.trajectory, vehicle, margin=MARGIN).ok}
        assert abs(ours.sum() - row['fastest_s']) < 1e-9 * row['fastest_s']
        if len(points) - 1 <= reference_max:
            t0 = time.process_time()
            best, starts = ref.best()
            row.update(reference_s=best.sum(), reference_cpu_s=time.process_time() - t0, starts=starts)
        rows.append(row)
        print(f'  {row}', file=sys.stderr, flush=True)
    return rows


def survey_points(n_segments):
    """bench_plan's survey route (quad_trajectory.survey), yaw 0."""
    return np.column_stack([survey_waypoints(n_segments), np.zeros(n_segments + 1)])


def timing_rows(vehicle):
    rows = []
    fastest.fastest_times(survey_points(5), vehicle)   # imports (scipy.optimize, scipy.sparse) not counted
    for n in SIZES:
        points = survey_points(n)
        cpu, wall = [], []
        for _ in range(RUNS):
            t0, c0 = time.perf_counter(), time.process_time()
            T = fastest.fastest_times(points, vehicle)
            wall.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
        ref = Reference(points, planner.PlanOptions(), vehicle)
        traj = planner.solve(points, T)
        rows.append({'segments': n, 'cpu_s': float(np.median(cpu)), 'wall_s': float(np.median(wall)),
                     'fastest_s': T.sum(), 'uniform_s': ref.scaled(timing.sqrt_allocation(points, 1.0)).sum(),
                     'ok': feasibility.check(traj, vehicle, margin=MARGIN).ok})
        print(f'  {rows[-1]}', file=sys.stderr, flush=True)
    return rows


def flown_rows(names, graph_names):
    controller, gains = load_control_profile(resolve_config(SE3_PROFILE))
    members = list(load_plant_family())
    rows = []
    for name in names:
        path = resolve_config(f'config/missions/{name}.yaml')
        for member in members:
            m = fly_offline(path, LoopOptions(controller=controller, gains=gains,
                                              plan_overrides={'time_allocation': 'fastest'},
                                              plant=None if member == 'nominal' else member))
            rows.append({'mission': name, 'plant': member, 'loop': 'offline', 'completed': bool(m['completed']),
                         'planned_s': m['time_planned_s'], 'actual_s': m.get('time_actual_s'), 'rmse_m': m['rmse_m'],
                         'max_m': m['max_error_m'], 'tilt_deg': m['max_tilt_deg']})
            print(f'  {rows[-1]}', file=sys.stderr, flush=True)
    if graph_names:
        import tempfile

        from quad_bringup.running.flight import fly
        from quad_bringup.running.flight_options import FlightOptions
        with tempfile.TemporaryDirectory(prefix='bench_fastest-') as tmp:
            for name in graph_names:
                result = fly(FlightOptions(mission=resolve_config(f'config/missions/{name}.yaml'), controller='se3',
                                           time_allocation='fastest', out=Path(tmp) / name, quiet=True),
                             log=lambda line: None)
                m = result.metrics or {}
                rows.append({'mission': name, 'plant': 'nominal', 'loop': 'graph (quadflight fly)',
                             'completed': result.exit_code == 0, 'planned_s': m.get('time_planned_s'),
                             'actual_s': m.get('time_actual_s'), 'rmse_m': m.get('rmse_m'),
                             'max_m': m.get('max_error_m'), 'tilt_deg': m.get('max_tilt_deg')})
                print(f'  {rows[-1]}', file=sys.stderr, flush=True)
    return rows


def fmt(value, spec):
    return '-' if value is None else format(value, spec)


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('--quick', action='store_true', help='reference on the small missions only, no graph flights')
    args = parser.parse_args()
    names = sorted(p.stem for p in (ROOT / 'config' / 'missions').glob('*.yaml'))
    vehicle = load_vehicle(resolve_config('config/vehicles/crazyflie.yaml'))
    plans = mission_rows(names, 8 if args.quick else REFERENCE_MAX_SEGMENTS)
    sizes = timing_rows(vehicle)
    flown = flown_rows(names, () if args.quick else GRAPH_MISSIONS)

    limits = feasibility.margined_limits(vehicle, MARGIN)
    print('### time_allocation fastest: the shortest feasible plan, against a brute-force reference\n')
    print(f'`fastest` (quad_trajectory/fastest.py) on the Crazyflie with a {100 * MARGIN:g} % margin: tilt and '
          f'lag-inclusive tilt <= {limits["tilt"][0]:.1f} deg, thrust <= {limits["thrust_max"][0]:.3f} N, rotor '
          f'speed <= {limits["rotor_speed_max"][0]:.0f} rad/s (and the lower limits raised by 10 % of their '
          'range), at feasibility.py\'s 32 samples a segment. Reference: scipy SLSQP over all segment times '
          f'with every (check, sample) as a constraint, from {2 + RANDOM_STARTS} starts (sqrt, proportional, '
          f'{RANDOM_STARTS} random shapes, each scaled to the limits by its own bisection), plus differential '
          f'evolution over the shape for missions of <= {DE_MAX_SEGMENTS} segments; the best is taken. '
          'It shares with fastest only the problem (feasibility.py\'s needs and margined limits) and the solver. '
          'sqrt: the seed\'s profile at the mission\'s own speed (feasible: yes/no on the vehicle without margin); '
          'limits: trajectory.limits or the defaults, slowed to pass the check; uniform: the sqrt shape scaled to '
          'the margined limits. Goal: fastest / reference <= 1.03.\n')
    print('| mission | segments (inserted) | sqrt at mission speed (s) | limits (s) | uniform sqrt (s) | fastest (s) '
          '| reference (s) | fastest / reference | fastest CPU (ms) | reference CPU (s) |')
    print('|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|')
    for r in plans:
        ratio = r['fastest_s'] / r['reference_s'] if 'reference_s' in r else None
        print(f'| {r["mission"]} | {r["segments"]} ({r["inserted"]}) | {r["sqrt_s"]:.2f} at {r["speed"]:g} m/s '
              f'({"feasible" if r["sqrt_ok"] else "NOT feasible"}) | {r["limits_s"]:.2f} | {r["uniform_s"]:.2f} | '
              f'{r["fastest_s"]:.3f}{"" if r["ok"] else " (FAILS its check)"} | {fmt(r.get("reference_s"), ".3f")} | '
              f'{fmt(ratio, ".4f")} | {1000 * r["fastest_cpu_s"]:.0f} | {fmt(r.get("reference_cpu_s"), ".1f")} |')
    ratios = [r['fastest_s'] / r['reference_s'] for r in plans if 'reference_s' in r]
    print(f'\nWorst fastest / reference: {max(ratios):.4f} over {len(ratios)} missions (goal <= 1.03: '
          f'{"met" if max(ratios) <= 1.03 else "NOT met"}).')
    print('\nCompute time of the allocation alone (fastest.fastest_times, CPU of this process, median of '
          f'{RUNS}; imports excluded) on bench_plan\'s survey missions (legs 0.4-1.2 m turning 0.7 rad). '
          'Goal: < 0.1 s for 100 segments, < 2 s for 1000.\n')
    print('| segments | CPU (s) | wall (s) | fastest (s) | uniform sqrt (s) | fastest / uniform | feasible |')
    print('|---:|---:|---:|---:|---:|---:|---|')
    for r in sizes:
        print(f'| {r["segments"]} | {r["cpu_s"]:.3f} | {r["wall_s"]:.3f} | {r["fastest_s"]:.2f} | '
              f'{r["uniform_s"]:.2f} | {r["fastest_s"] / r["uniform_s"]:.3f} | {"yes" if r["ok"] else "NO"} |')
    print()
    for n, goal in ((100, 0.1), (1000, 2.0)):
        cpu = next(r['cpu_s'] for r in sizes if r['segments'] == n)
        print(f'{n} segments: {cpu:.2f} s CPU against the goal of {goal:g} s: '
              + ('met.' if cpu <= goal else f'NOT met, {cpu / goal:.1f}x over.'))
    print('\nFlown with `--time-allocation fastest` and the default se3 profile (config/control_se3.yaml): the '
          'offline loop on the nominal Crazyflie and each plant family member (config/plant_family.yaml), and '
          '`quadflight fly` through the ROS graph. Goal: completes, RMSE < 2 cm and peak tilt < '
          f'{limits["tilt"][0]:.1f} deg (inside the margin) nominal; RMSE < 5 cm on every member.\n')
    print('| mission | plant | loop | completed | planned (s) | actual (s) | RMSE (cm) | max error (cm) '
          '| peak tilt (deg) |')
    print('|---|---|---|---|---:|---:|---:|---:|---:|')
    for r in flown:
        print(f'| {r["mission"]} | {r["plant"]} | {r["loop"]} | {"yes" if r["completed"] else "NO"} | '
              f'{fmt(r["planned_s"], ".2f")} | {fmt(r["actual_s"], ".2f")} | '
              f'{fmt(r["rmse_m"] and 100 * r["rmse_m"], ".2f")} | {fmt(r["max_m"] and 100 * r["max_m"], ".2f")} | '
              f'{fmt(r["tilt_deg"], ".1f")} |')
    nominal = [r for r in flown if r['plant'] == 'nominal']
    members = [r for r in flown if r['plant'] != 'nominal']
    worst_nominal = max(r['rmse_m'] for r in nominal)
    worst_member = max(members, key=lambda r: r['rmse_m'])
    print(f'\nAll {len(flown)} flights completed: {"yes" if all(r["completed"] for r in flown) else "NO"}. '
          f'Nominal: worst RMSE {100 * worst_nominal:.2f} cm (goal < 2), peak tilt '
          f'{max(r["tilt_deg"] for r in nominal):.1f} deg (goal < {limits["tilt"][0]:.1f}); plant members: worst '
          f'RMSE {100 * worst_member["rmse_m"]:.2f} cm ({worst_member["mission"]}, {worst_member["plant"]}; goal < 5), '
          f'peak tilt {max(r["tilt_deg"] for r in members):.1f} deg (the vehicle\'s {vehicle.max_tilt_deg:g} deg).')


if __name__ == '__main__':
    main()
