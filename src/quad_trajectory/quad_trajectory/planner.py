"""Plan a trajectory through waypoints: validate, merge near-duplicates, add control points, allocate
times, solve (solver.py), and, in a world, replan until collision-free.

Bad input raises ValueError naming the field and the value.
"""

import json
from dataclasses import dataclass, field

import numpy as np

from quad_common.vehicle import Vehicle
from quad_common.world import World
from quad_trajectory import collision, fastest, feasibility, generated, solver, timing
from quad_trajectory.plan_inputs import (
    PlanOptions,
    check_option_values,
    finite_number,
    waypoint_rows,
    yaw_values,
)
from quad_trajectory.polynomial import PiecewisePolynomial

MERGE_DISTANCE_M = 1e-3
MAX_REPLANS = 12
_LIMIT_TARGET = 0.97   # plan to 97 % of v_max / a_max so that samples between ours stay inside too
_LIMIT_ITERATIONS = 8
_FIT_STEPS = 30                 # limits with a vehicle: at most 1.1^30 = 17x slower to pass its feasibility check
MAX_LIMITS_LENGTH_RATIO = 1.5   # limits: a faster shape is taken only while its path stays this short
ABSURD_LENGTH_RATIO = 10.0      # no plan longer than this x the polyline through its points is returned
MIN_MEAN_SPEED_MPS = 1e-3       # nor one slower on average along that polyline (the 2.1e11 s plan: 1e-10 m/s)


@dataclass
class MergedWaypoint:
    index: int          # the dropped waypoint (input numbering)
    into_index: int     # the kept waypoint it was merged into
    distance_m: float

    def __str__(self):
        return (f'waypoint {self.index} merged into waypoint {self.into_index} '
                f'({self.distance_m * 1000:.3f} mm apart, < {MERGE_DISTANCE_M * 1000:g} mm)')


@dataclass
class PlanResult:
    trajectory: PiecewisePolynomial
    waypoints: np.ndarray        # (K, 3) waypoints planned through, after merging
    yaw: np.ndarray              # (K,) unwrapped yaw at those waypoints
    points: np.ndarray           # (M + 1, 4) every point a segment ends at: waypoints, control and inserted points
    is_waypoint: np.ndarray      # (M + 1,) True where points[i] is a mission waypoint
    options: PlanOptions
    merged: list = field(default_factory=list)
    inserted_points: int = 0     # points added by collision replanning
    world: World | None = None
    _summary: dict | None = field(default=None, repr=False)

    def waypoint_times_s(self) -> np.ndarray:
        return self.trajectory.breaks_s[self.is_waypoint]

    def summary(self) -> dict:
        """Counts and peaks (computed once: each peak is a pass over 128 samples of every segment)."""
        if self._summary is None:
            self._summary = self._compute_summary()
        return dict(self._summary)

    def _compute_summary(self) -> dict:
        t = self.trajectory
        return {'segments': t.n_segments, 'waypoints': len(self.waypoints), 'merged_waypoints': len(self.merged),
                'inserted_points': self.inserted_points, 'time_planned_s': t.duration_s,
                'length_planned_m': t.arc_length(), 'max_speed_mps': t.max_speed(),
                'max_acceleration_mps2': t.max_acceleration(), 'max_jerk_mps3': t.max_jerk()}

    def to_dict(self, segments=True) -> dict:
        """The plan JSON layout of docs/design.md (waypoints, segments) plus what else the plan knows."""
        o = self.options
        return {'waypoints': self.waypoints.tolist(), 'segments': self.trajectory.to_dict()['segments'] if segments
                else None,
                'yaw': self.yaw.tolist(), 'points': self.points.tolist(), 'is_waypoint': self.is_waypoint.tolist(),
                'method': o.method, 'waypoint_constraint': o.waypoint_constraint, 'speed_mps': o.speed_mps,
                'time_allocation': o.time_allocation, 'control_points': list(o.control_points),
                'robot_radius_m': o.robot_radius_m, 'merged': [m.__dict__ for m in self.merged],
                'summary': self.summary()}

    def to_json(self, **head) -> str:
        """json.dumps({**head, **self.to_dict()}) with the segments written by segments_json (no per-value
        Python loop; a 100k-segment plan in a fraction of a second)."""
        text = json.dumps({**head, **self.to_dict(segments=False)})
        # the key is unique: a quote inside any string value is escaped, so '"segments": null' is only the key
        return text.replace('"segments": null', '"segments": ' + self.trajectory.segments_json(), 1)


# --- validation -----------------------------------------------------------------------------

def validate_waypoints(waypoints) -> np.ndarray:
    """(N, 3) waypoints (quad_trajectory.plan_inputs.waypoint_rows checks them)."""
    return np.asarray(waypoint_rows(waypoints), dtype=float)


def validate_yaw(yaw, n: int) -> np.ndarray:
    """None -> 0; one value -> constant; one per waypoint -> unwrapped (plan_inputs.yaw_values checks them)."""
    values = yaw_values(yaw, n)
    if values is None:
        return np.zeros(n)
    return np.full(n, values) if isinstance(values, float) else np.unwrap(np.asarray(values, dtype=float))


def validate_options(o: PlanOptions, vehicle: Vehicle | None = None) -> PlanOptions:
    """Each option's own rule (plan_inputs.check_option_values), then what needs the vehicle, and a generator's
    class resolved."""
    check_option_values(o)
    if o.a_max_mps2 is not None and vehicle is not None:
        cap = timing.vehicle_acceleration_capability(vehicle.thrust_to_weight)
        if o.a_max_mps2 > cap:
            raise ValueError(f'limits.a_max_mps2 = {o.a_max_mps2} cannot be met: vehicle {vehicle.name} gives at most '
                             f'g (thrust/weight - 1) = {cap:.2f} m/s^2')
    if o.time_allocation == 'fastest' and vehicle is None:
        raise ValueError('time_allocation = fastest needs a vehicle (its limits are what it flies to)')
    if o.generator:
        generated.resolve(o.generator)
        if o.generator_args is not None and not isinstance(o.generator_args, dict):
            raise ValueError(f'generator_args = {o.generator_args!r} must be a mapping of keyword arguments')
        if not isinstance(o.generator_waypoints, bool):
            raise ValueError(f'generator_waypoints = {o.generator_waypoints!r} must be true or false')
        if o.duration_s is not None:
            finite_number('duration_s', o.duration_s)
    return o


def merge_close_waypoints(waypoints, yaw):
    """Drop each waypoint closer than 1 mm to the previous kept one; returns (kept, yaw, merged reports)."""
    if np.all(np.linalg.norm(np.diff(waypoints, axis=0), axis=1) >= MERGE_DISTANCE_M):
        return waypoints, yaw, []
    keep, merged = [0], []
    for i in range(1, len(waypoints)):
        d = float(np.linalg.norm(waypoints[i] - waypoints[keep[-1]]))
        if d < MERGE_DISTANCE_M:
            merged.append(MergedWaypoint(index=i, into_index=keep[-1], distance_m=d))
        else:
            keep.append(i)
    if len(keep) < 2:
        raise ValueError(f'waypoints = {waypoints.tolist()} needs at least two distinct waypoints '
                         f'(all are within {MERGE_DISTANCE_M * 1000:g} mm of the first)')
    return waypoints[keep], yaw[keep], merged


def add_control_points(points, fractions):
    """The seed's improvement (5.3): on each leg (a, b) insert a + f (b - a) for f in fractions."""
    f = np.sort(np.asarray(fractions, dtype=float))
    if f.size == 0:
        return points, np.ones(len(points), dtype=bool)
    a, b = points[:-1], points[1:]
    inner = a[:, None, :] + f[None, :, None] * (b - a)[:, None, :]  # (legs, F, 4)
    legs = np.concatenate([a[:, None, :], inner], axis=1).reshape(-1, points.shape[1])
    mask = np.tile(np.r_[True, np.zeros(f.size, dtype=bool)], len(a))
    return np.vstack([legs, points[-1:]]), np.append(mask, True)


# --- solving --------------------------------------------------------------------------------

def solve(points, durations_s, method='minsnap', mode='continuity') -> PiecewisePolynomial:
    r = solver.ORDERS[method]
    return PiecewisePolynomial(durations_s, solver.solve_banded_coefficients(durations_s, points, r, mode))


def _limit_shape(points, durations, o: PlanOptions, v_max, a_max):
    """Solve with `durations` and return (trajectory, per-segment ratio k_i, k = max k_i) where
    k_i = max(peak speed_i / v_max, sqrt(peak acceleration_i / a_max))."""
    traj = solve(points, durations, o.method, o.waypoint_constraint)
    k_i = np.maximum(traj.segment_peaks(1) / v_max, np.sqrt(traj.segment_peaks(2) / a_max))
    return traj, k_i, float(k_i.max())


def _fit_vehicle(points, durations, o: PlanOptions, vehicle):
    """Slow the plan down uniformly (x1.1 a step, at most _FIT_STEPS) until it passes the vehicle's feasibility
    check (tilt, thrust, rotors, the attitude loop's lag; quad_trajectory.feasibility). Uniform scaling is exact
    (see _limit_times) and tends to hover as it grows, so this ends wherever hover itself is feasible."""
    T = durations
    for _ in range(_FIT_STEPS):
        if feasibility.check(solve(points, T, o.method, o.waypoint_constraint), vehicle).ok:
            break
        T = T * 1.1
    return T


def _limit_times(points, durations, o: PlanOptions, v_max, a_max):
    """Segment times that meet v_max and a_max, as fast as a bounded search finds, never an absurd plan.

    Uniform time scaling is exact: the problem with times k T (same points and constraints) is solved by
    p(t / k), because every constraint row is invariant and the cost scales by k^(1 - 2r) for all candidates
    alike. Speed then divides by k and acceleration by k^2, so for any shape T (times up to a common factor)
    k = max_i k_i makes the plan meet both limits with the binding one reached, in one solve.

    The search is over shapes only: from the seed's sqrt shape T0, slack segments (k_i < k) are shortened by
    (k_i / k)^(1/2), at most a factor 2 per step, and every shape stays within a factor 4 of T0 (after
    removing the common scale). Each of the _LIMIT_ITERATIONS + 1 shapes is a candidate, scaled by its own k.
    Bounds, by construction rather than by convergence of the iteration:
    - termination: exactly _LIMIT_ITERATIONS + 1 solves;
    - limits: every candidate meets them at its 128 samples per segment (the 0.97 target covers the rest);
    - length: scaling does not change the path, so the returned one is the fastest candidate whose length
      is <= MAX_LIMITS_LENGTH_RATIO x the polyline, else the shortest candidate (the sqrt shape is one; on
      random 30-leg missions of 0.4-1.2 m legs its path is <= 1.3x the polyline, the returned <= 1.43x);
    - duration: <= that of the sqrt shape scaled to the limits whenever that shape meets the length bound.
    check_sane then refuses any plan that is still absurd.
    The old per-segment rescaling (T_i *= sqrt k_i, repeated) had no such bound: a stretched segment
    drifts further at its neighbours' joint speed, is stretched again, and ran away to 1e11 s and 1e11 m.
    """
    poly = float(timing.segment_lengths(points).sum())
    T0 = np.asarray(durations, dtype=float)
    T, best, shortest = T0.copy(), None, None
    for _ in range(_LIMIT_ITERATIONS + 1):
        traj, k_i, k = _limit_shape(points, T, o, v_max, a_max)
        candidate = (T * k, traj.arc_length())
        if candidate[1] <= MAX_LIMITS_LENGTH_RATIO * poly and (best is None or candidate[0].sum() < best[0].sum()):
            best = candidate
        if shortest is None or candidate[1] < shortest[1]:
            shortest = candidate
        shape = T * np.clip(k_i / k, 0.5, 1.0) ** 0.5 / T0
        shape = shape / np.exp(np.mean(np.log(shape)))
        T = T0 * np.clip(shape, 0.25, 4.0)
    return (best or shortest)[0]


def check_sane(trajectory: PiecewisePolynomial, points, o: PlanOptions) -> PiecewisePolynomial:
    """Refuse a plan whose length or duration is absurd (ValueError naming both), whatever produced it."""
    poly = float(timing.segment_lengths(points).sum())
    length = trajectory.arc_length()
    max_duration_s = poly / MIN_MEAN_SPEED_MPS
    if not (np.isfinite(length) and length <= ABSURD_LENGTH_RATIO * poly) or \
            not trajectory.duration_s <= max_duration_s:
        raise ValueError(f'the planned trajectory is absurd: {length:.6g} m long ({length / poly:.3g} x the '
                         f'{poly:.3f} m polyline; at most {ABSURD_LENGTH_RATIO:g} x) and {trajectory.duration_s:.6g} s '
                         f'(at most {max_duration_s:.6g} s: {MIN_MEAN_SPEED_MPS * 1000:g} mm/s on average) with '
                         f'time_allocation = {o.time_allocation}, speed = {o.speed_mps} m/s')
    return trajectory


def _optimal_times(points, durations, o: PlanOptions):
    """Minimise J(T) = cost(T) / cost(T0) + rho sum(T) / sum(T0) over log T, starting from T0.

    With rho = 2r - 1 (default) the optimum along uniform scaling is T0 itself, so the seed's total
    time L / speed is kept near while the split between segments is optimised.
    """
    from scipy.optimize import minimize  # only this allocation needs it (0.5 s of import)

    r = solver.ORDERS[o.method]
    rho = o.rho if o.rho is not None else 2 * r - 1.0

    def cost(T):
        c = solver.solve_banded_coefficients(T, points, r, o.waypoint_constraint)
        return solver.derivative_cost(T, c, r)

    c0, s0 = cost(durations), durations.sum()
    res = minimize(lambda x: cost(np.exp(x)) / c0 + rho * np.exp(x).sum() / s0, np.log(durations),
                   method='L-BFGS-B', options={'maxiter': 200})
    return np.exp(res.x)


def limits_of(o: PlanOptions, vehicle: Vehicle | None = None) -> dict:
    """What `limits` plans to: {'v_max_mps', 'a_max_mps2'} with where each comes from ('v_max_source', ...).
    These are maxima (the mission's trajectory.limits, else the defaults), not the average speed."""
    if o.v_max_mps is not None:
        v_max, v_source = o.v_max_mps, 'trajectory.limits.v_max_mps'
    else:
        v_max, v_source = timing.DEFAULT_V_MAX_MPS, 'the default (trajectory.limits.v_max_mps not set)'
    if o.a_max_mps2 is not None:
        a_max, a_source = o.a_max_mps2, 'trajectory.limits.a_max_mps2'
    elif vehicle is not None:
        a_max = timing.vehicle_acceleration_limit(vehicle.thrust_to_weight)
        a_source = (f'{timing.ACCELERATION_SHARE:g} g (thrust/weight - 1) of {vehicle.name}, thrust/weight '
                    f'{vehicle.thrust_to_weight:.2f}')
    else:
        raise ValueError('time_allocation = limits needs limits.a_max_mps2 or a vehicle')
    return {'v_max_mps': float(v_max), 'v_max_source': v_source, 'a_max_mps2': float(a_max), 'a_max_source': a_source}


def allocation_lines(result: 'PlanResult', vehicle: Vehicle | None = None) -> list[str]:
    """What the allocation planned to and how much of it the plan uses (limits and fastest; else none)."""
    o, t = result.options, result.trajectory
    if o.time_allocation == 'limits':
        lim = limits_of(o, vehicle)
        v, a = t.max_speed(), t.max_acceleration()
        return [f'limits: v_max {lim["v_max_mps"]:g} m/s ({lim["v_max_source"]}), a_max {lim["a_max_mps2"]:.3g} m/s^2 '
                f'({lim["a_max_source"]}), planned to {100 * _LIMIT_TARGET:.0f} % of each: peak speed {v:.3f} m/s '
                f'({100 * v / lim["v_max_mps"]:.0f} %), peak acceleration {a:.3f} m/s^2 '
                f'({100 * a / lim["a_max_mps2"]:.0f} %)'
                + ('' if vehicle is None else
                   '; with the vehicle, slowed down uniformly where needed until it passes its feasibility check')]
    if o.time_allocation == 'fastest' and vehicle is not None:
        report = feasibility.check(t, vehicle, margin=o.margin)
        used = ', '.join(f'{k} {report.peaks[k]:.4g} / {lim:.4g} {unit}' for k, (lim, unit) in report.limits.items())
        return [f'fastest: the shortest plan found within {vehicle.name}\'s limits less {100 * o.margin:g} % '
                f'(need / limit: {used})']
    return []


def allocate_times(points, o: PlanOptions, vehicle: Vehicle | None = None) -> np.ndarray:
    if o.time_allocation == 'proportional':
        return timing.proportional_allocation(points, o.speed_mps)
    T = timing.sqrt_allocation(points, o.speed_mps)
    if o.time_allocation == 'limits':
        lim = limits_of(o, vehicle)
        T = _limit_times(points, T, o, _LIMIT_TARGET * lim['v_max_mps'], _LIMIT_TARGET * lim['a_max_mps2'])
        return T if vehicle is None else _fit_vehicle(points, T, o, vehicle)
    if o.time_allocation == 'optimal':
        return _optimal_times(points, T, o)
    if o.time_allocation == 'fastest':
        if vehicle is None:
            raise ValueError('time_allocation = fastest needs a vehicle (its limits are what it flies to)')
        return fastest.fastest_times(points, vehicle, o.method, o.waypoint_constraint, o.margin)
    return T


def plan(waypoints, yaw=None, options: PlanOptions | None = None, world: World | None = None,
         vehicle: Vehicle | None = None) -> PlanResult:
    o = validate_options(options or PlanOptions(), vehicle)
    w = validate_waypoints(waypoints)
    y = validate_yaw(yaw, len(w))
    if o.generator:   # a user's class makes the plan (generated.py); its own start and end are the plan's waypoints
        traj, samples = generated.generate(w, o, world)
        ends = np.zeros(len(samples), dtype=bool)
        ends[[0, -1]] = True
        return PlanResult(trajectory=traj, waypoints=samples[ends, :3], yaw=samples[ends, 3], points=samples,
                          is_waypoint=ends, options=o, world=world)
    w, y, merged = merge_close_waypoints(w, y)
    points, is_waypoint = add_control_points(np.column_stack([w, y]), o.control_points or ())
    if world is not None:
        bad = collision.polyline_collisions(world, w, o.robot_radius_m)
        if bad.size:
            i = int(bad[0])
            raise ValueError(f'waypoints: the straight leg {w[i].tolist()} -> {w[i + 1].tolist()} comes within '
                             f'robot_radius_m = {o.robot_radius_m} of an obstacle or the bounds of {world.name}: '
                             f'no trajectory through these waypoints can be collision-free')
    inserted = 0
    for attempt in range(MAX_REPLANS + 1):
        traj = check_sane(solve(points, allocate_times(points, o, vehicle), o.method, o.waypoint_constraint),
                          points, o)
        if world is None:
            break
        segments, times = collision.trajectory_collisions(world, traj, o.robot_radius_m)
        if segments.size == 0:
            break
        if not o.avoid_collisions or attempt == MAX_REPLANS:
            raise ValueError(f'trajectory collides with {world.name} at t = {times[0]:.3f} s '
                             f'(robot_radius_m = {o.robot_radius_m}, {len(segments)} segments'
                             + (f', still after inserting {inserted} points)' if o.avoid_collisions else ')'))
        # pull each colliding segment onto its straight leg: insert the leg's midpoint
        mid = 0.5 * (points[segments] + points[segments + 1])
        points = np.insert(points, segments + 1, mid, axis=0)
        is_waypoint = np.insert(is_waypoint, segments + 1, False)
        inserted += len(segments)
    return PlanResult(trajectory=traj, waypoints=w, yaw=y, points=points, is_waypoint=is_waypoint, options=o,
                      merged=merged, inserted_points=inserted, world=world)
