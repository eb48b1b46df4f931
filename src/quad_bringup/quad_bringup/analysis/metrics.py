"""Flight metrics without ROS (numpy only): the completion rule (quad_bringup.analysis.completion) and the numbers of
the seed's Table 1/2 plus errors, computed from arrays over time. `quadflight report` (from a bag), fly's live verdict
and the offline loop (quad_bringup.offline.closed_loop) all use these, so each number has one definition
(docs/quad_bringup.md).

Definitions:
- time_planned_s: duration of the `trajectory` plan.
- time_actual_s: from the trajectory start (its header.stamp) until completion, i.e. the first
  odometry at which |p - p_final| <= position_tolerance_m and |v| <= speed_tolerance_mps, searched
  from the moment the plan itself stays inside that ball (a flight cannot finish before its plan);
  without completion, until the plan's end plus settle_s (or the bag's last odometry, if earlier):
  a real estimator may never meet a simulator's tolerance, and the window must not run into the
  landing. This is the scored window; metrics.json `scored_window` and report.md say which end it had.
- The tolerances and settle_s: the vehicle's `completion:` in its YAML (Completion.for_vehicle), else
  the course simulator's 2 cm / 0.03 m/s; a command-line value overrides either.
- length_*_m: arc length of the planned samples / of the odometry positions over time_actual_s.
- avg_velocity_mps = length_actual_m / time_actual_s (the seed's column).
- rmse_m, max_error_m: |p_actual(t) - p_planned(t - t_start)| over that window (plan held at its ends).
- waypoint_miss_max_m: the largest over waypoints of the closest approach of the flown path.
- record: the bag checked against the simulator: distinct odom and /clock stamps in the bag vs the steps
  sim_node says it published (its `sim_node: published` diagnostics, the newest in the bag, or the final count
  fly passes), and gaps in the odometry longer than 1.5 lockstep periods. A shortfall is reported, never silent.
"""

from dataclasses import dataclass, field

import numpy as np

from quad_bringup.analysis.completion import Completion  # noqa: F401  (re-exported: the rule beside its metrics)


@dataclass
class Flight:
    """What a bag says about one flight, as arrays over header-stamp time (s)."""
    odom_t: np.ndarray
    position: np.ndarray          # (N, 3) map
    velocity: np.ndarray          # (N, 3) map
    euler: np.ndarray             # (N, 3) roll, pitch, yaw
    traj_start_s: float | None = None
    trajectory: object = None     # SampledTrajectory
    waypoints: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    obstacles: list = field(default_factory=list)  # (centre (3,), size (3,))
    cmd_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    cmd_specific_force: np.ndarray = field(default_factory=lambda: np.zeros(0))
    cmd_euler: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    collision_time_s: float | None = None
    errors: list = field(default_factory=list)   # (time_s, name, message) of ERROR diagnostics
    odom_stamps_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    odom_record_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))   # in odom_t's order
    clock_stamps_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    sim_published: tuple | None = None           # (stamp ns, steps) of the newest `sim_node: published`
    collisions_known: bool = True                # False: nothing in the bag could report one (no simulator)
    truncated: dict | None = None                # a killed recorder's bag: where it was cut (recorder.Repair)
    cmd_record_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # bag time of each cmd
    engaged: list = field(default_factory=list)  # (bag time ns, bool) of each vehicle/engaged message
    handover: list = field(default_factory=list)  # (bag time ns, phase) of the bridge's `handover` diagnostics
    controller_odom_age: list = field(default_factory=list)  # (bag time ns, ms): the controller's reported
    #                                       mean odometry age (contract.CONTROLLER_ODOM_AGE_MS)


GAP_FACTOR = 1.5  # an odometry interval longer than this many typical periods is a gap


# --- metrics -------------------------------------------------------------------------------------

def record_check(flight: Flight, published: tuple | None = None) -> dict:
    """The bag against the simulator's own count (module docstring): steps published, distinct stamps recorded
    up to the count's stamp, what is missing, and the odometry gaps. published: (stamp ns, steps) of a
    `sim_node: published` the caller saw (fly's monitor); the newer of it and the bag's newest counts (a count
    is checked up to its own stamp: one a loaded monitor received late is not held against steps after it)."""
    odom = np.unique(flight.odom_stamps_ns)
    clock = np.unique(flight.clock_stamps_ns)
    counts = [c for c in (published, flight.sim_published) if c is not None]
    upto, published_steps = max(counts, key=lambda c: c[0]) if counts else (None, None)
    check = {'steps_published': published_steps}
    for name, stamps in (('odom', odom), ('/clock', clock)):
        recorded = int(np.count_nonzero(stamps <= upto)) if upto is not None else int(len(stamps))
        check[f'{name}_recorded'] = recorded
        if published_steps is not None and recorded < published_steps:
            check.setdefault('missing', {})[name] = published_steps - recorded
    gaps = []
    if len(odom) > 2:
        dt = np.diff(odom)
        period = float(np.median(dt))
        for i in np.nonzero(dt > GAP_FACTOR * period)[0][:10]:
            gaps.append({'after_s': float(odom[i] * 1e-9), 'length_s': float(dt[i] * 1e-9)})
    check['gaps'] = gaps
    check['complete'] = published_steps is not None and 'missing' not in check and not gaps
    return check


def record_summary(check: dict) -> str:
    """One line: what the bag holds against what the simulator published."""
    if check['steps_published'] is None:
        return 'record: the bag has no count from sim_node to check against'
    line = (f'record: odom {check["odom_recorded"]} and /clock {check["/clock_recorded"]} of '
            f'{check["steps_published"]} steps published by sim_node')
    if check.get('missing'):
        line += '; MISSING ' + ', '.join(f'{n} {t}' for t, n in check['missing'].items())
    if check['gaps']:
        line += (f'; {len(check["gaps"])} gap(s) in odom, the longest {max(g["length_s"] for g in check["gaps"]):.3f}'
                 f' s after t = {check["gaps"][0]["after_s"]:.2f} s')
    return line + ('' if check['complete'] else ' (INCOMPLETE)')



def arc_length(points) -> float:
    points = np.asarray(points)
    return float(np.sum(np.linalg.norm(np.diff(points, axis=0), axis=1))) if len(points) > 1 else 0.0


def closest_approach(path, point) -> float:
    """Distance from `point` to the polyline `path` (segments, not just samples)."""
    path = np.asarray(path)
    if len(path) == 1:
        return float(np.linalg.norm(path[0] - point))
    a, b = path[:-1], path[1:]
    ab = b - a
    s = np.clip(np.einsum('ij,ij->i', point - a, ab) / np.maximum(np.einsum('ij,ij->i', ab, ab), 1e-18), 0, 1)
    return float(np.min(np.linalg.norm(a + s[:, None] * ab - point, axis=1)))


def planned_position(flight: Flight, t_s) -> np.ndarray:
    """The plan's position at absolute times t_s (held at its ends)."""
    return flight.trajectory.evaluate(np.asarray(t_s) - flight.traj_start_s, order=0)[0][..., :3]


def completion_time(flight: Flight, rule: Completion) -> float | None:
    """Absolute time of completion (see module docstring), or None."""
    arrival_s = rule.plan_arrival_s(flight.trajectory)
    done = rule.done(flight.odom_t - flight.traj_start_s, flight.position, flight.velocity, flight.trajectory,
                     arrival_s)
    return float(flight.odom_t[np.argmax(done)]) if np.any(done) else None


def compute_metrics(flight: Flight, rule: Completion = Completion(), published: tuple | None = None) -> dict:
    if flight.trajectory is None:
        raise ValueError('bag has no trajectory message (topic trajectory): nothing to compare the flight with')
    t0 = flight.traj_start_s
    t_done = completion_time(flight, rule)
    settled = t0 + flight.trajectory.duration_s + rule.settle_s
    if t_done is not None:
        t_end, ends_at = t_done, 'completion'
    elif settled <= flight.odom_t[-1]:
        t_end, ends_at = settled, f"the plan's end + settle_s {rule.settle_s:g} s (no completion)"
    else:
        t_end, ends_at = float(flight.odom_t[-1]), "the bag's last odometry (no completion)"
    window = (flight.odom_t >= t0) & (flight.odom_t <= t_end)
    if not np.any(window):
        window = flight.odom_t <= t_end
    p = flight.position[window]
    err = np.linalg.norm(p - planned_position(flight, flight.odom_t[window]), axis=1)
    time_actual = t_end - t0
    length_actual = arc_length(p)
    collided = flight.collision_time_s is not None
    waypoints = flight.waypoints if len(flight.waypoints) else flight.trajectory.position[[0, -1], :3]
    misses = [closest_approach(p, w) for w in waypoints]
    final = flight.trajectory.position[-1, :3]
    metrics = {
        'time_planned_s': flight.trajectory.duration_s,
        'time_actual_s': time_actual,
        'time_over_s': time_actual - flight.trajectory.duration_s,
        'length_planned_m': arc_length(flight.trajectory.position[:, :3]),
        'length_actual_m': length_actual,
        'avg_velocity_mps': length_actual / time_actual if time_actual > 0 else 0.0,
        'rmse_m': float(np.sqrt(np.mean(err ** 2))),
        'max_error_m': float(np.max(err)),
        'waypoint_miss_max_m': float(max(misses)),
        'completed': t_done is not None and not collided,
        'collided': collided if collided or flight.collisions_known else None,   # None: n/a (a real flight)
        'collision_time_s': None if not collided else flight.collision_time_s - t0,
        'final_error_m': float(np.linalg.norm(flight.position[-1] - final)),
        # a flight that began away from the plan's start joins it, and its first errors are the join
        'start_offset_m': float(np.linalg.norm(flight.position[int(np.argmin(np.abs(flight.odom_t - t0)))]
                                               - flight.trajectory.position[0, :3])),
        'max_speed_mps': float(np.max(np.linalg.norm(flight.velocity[window], axis=1))),
        'max_tilt_deg': float(np.degrees(np.max(np.arccos(np.clip(
            np.cos(flight.euler[window, 0]) * np.cos(flight.euler[window, 1]), -1, 1))))),
        'n_waypoints': int(len(waypoints)),
        'n_odometry': int(np.count_nonzero(window)),
        'errors': [f'{t - t0:.2f} s {name}: {message}' for t, name, message in flight.errors[:10]],
        'completion_rule': rule.describe(),
        'scored_window': {'start_s': 0.0, 'end_s': t_end - t0, 'ends_at': ends_at,
                          'bag_end_s': float(flight.odom_t[-1]) - t0},
        'record': record_check(flight, published),
        'bag_truncated': flight.truncated,
    }
    return metrics
