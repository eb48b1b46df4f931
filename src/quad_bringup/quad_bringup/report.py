"""Flight report from a rosbag2 bag (no rclpy): the seed's Table 1/2 columns, errors and Figures 1-5.

Reads any rosbag2 bag (MCAP or sqlite3, ours or `ros2 bag record`'s) with `rosbags`,
deserialising with its ROS 2 Jazzy typestore; the messages it yields have the rclpy field names,
so the shared converters of quad_common.conversions read them.

Times are message header stamps (simulated time in lockstep). Definitions (docs/quad_bringup.md):
- time_planned_s: duration of the `trajectory` plan.
- time_actual_s: from the trajectory start (its header.stamp) until completion, i.e. the first
  odometry at which |p - p_final| <= position_tolerance_m and |v| <= speed_tolerance_mps, searched
  from the moment the plan itself stays inside that ball (a flight cannot finish before its plan);
  without completion, until the last odometry of the bag.
- length_*_m: arc length of the planned samples / of the odometry positions over time_actual_s.
- avg_velocity_mps = length_actual_m / time_actual_s (the seed's column).
- rmse_m, max_error_m: |p_actual(t) - p_planned(t - t_start)| over that window (plan held at its ends).
- waypoint_miss_max_m: the largest over waypoints of the closest approach of the flown path.
- record: the bag checked against the simulator: distinct odom and /clock stamps in the bag vs the steps
  sim_node says it published (its `sim_node: published` diagnostics, the newest in the bag, or the final count
  fly passes), and gaps in the odometry longer than 1.5 lockstep periods. A shortfall is reported, never silent.
"""

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from quad_bringup.recorder import open_bag_reader, typestore
from quad_common import conversions, rotations
from quad_common.diagnostics import ERROR, level_of

ODOM, TRAJECTORY, WAYPOINTS, MARKERS = 'odom', 'trajectory', 'trajectory/waypoints', 'trajectory/markers'
COMMAND, DIAGNOSTICS, CLOCK = 'cmd/attitude_thrust', 'diagnostics', 'clock'
SIM_PUBLISHED = 'sim_node: published'
GAP_FACTOR = 1.5  # an odometry interval longer than this many typical periods is a gap
ERROR_LEVEL = ERROR[0]  # diagnostic_msgs levels are bytes in rclpy, ints from rosbags


@dataclass(frozen=True)
class Completion:
    """The course simulator's completion rule (configurable): the one definition that fly's live
    verdict and the report's time_actual_s both use."""
    position_tolerance_m: float = 0.02
    speed_tolerance_mps: float = 0.03

    def plan_arrival_s(self, trajectory) -> float:
        """Time since the trajectory's start after which the plan itself stays within the tolerance
        of its final point (so a loop that passes its end early is not 'complete' at take-off)."""
        final = trajectory.position[-1, :3]
        outside = np.linalg.norm(trajectory.position[:, :3] - final, axis=1) > self.position_tolerance_m
        return float(trajectory.times_s[np.nonzero(outside)[0][-1] + 1] - trajectory.times_s[0]
                     if np.any(outside) else 0.0)

    def done(self, elapsed_s, position, velocity, trajectory, arrival_s):
        """Completion test for one sample or arrays of them (positions/velocities on the last axis)."""
        final = trajectory.position[-1, :3]
        return ((np.asarray(elapsed_s) >= arrival_s)
                & (np.linalg.norm(np.asarray(position) - final, axis=-1) <= self.position_tolerance_m)
                & (np.linalg.norm(velocity, axis=-1) <= self.speed_tolerance_mps))


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
    clock_stamps_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    sim_published: tuple | None = None           # (stamp ns, steps) of the newest `sim_node: published`
    truncated: dict | None = None                # a killed recorder's bag: where it was cut (recorder.Repair)


def _namespaced(topic: str, wanted: str) -> bool:
    """'odom' matches 'odom', '/odom' and '/uav1/odom' (a namespaced flight)."""
    return topic.lstrip('/') == wanted or topic.endswith('/' + wanted)


def load_flight(bag_dir) -> Flight:
    """Extract a Flight from a bag; raises ValueError naming what is missing."""
    ts = typestore()
    odom, cmds, latest, clock = [], [], {}, []
    errors, collision, published = [], None, None
    reader, repair = open_bag_reader(bag_dir)
    try:
        wanted = (ODOM, TRAJECTORY, WAYPOINTS, MARKERS, COMMAND, DIAGNOSTICS, CLOCK)
        connections = [c for c in reader.connections if any(_namespaced(c.topic, w) for w in wanted)]
        for conn, _, raw in reader.messages(connections=connections):
            msg = ts.deserialize_cdr(raw, conn.msgtype)
            topic = next(w for w in wanted if _namespaced(conn.topic, w))
            if topic == ODOM:
                odom.append((conversions.stamp_to_s(msg.header.stamp), conversions.odometry_to_state(msg),
                             _ns(msg.header.stamp)))
            elif topic == CLOCK:
                clock.append(_ns(msg.clock))
            elif topic == COMMAND:
                cmds.append((conversions.stamp_to_s(msg.header.stamp), msg.linear_acceleration.z,
                             conversions.quat(msg.orientation)))
            elif topic == DIAGNOSTICS:
                for st in msg.status:
                    if st.name == SIM_PUBLISHED:
                        steps = int({kv.key: kv.value for kv in st.values}.get('steps', -1))
                        if published is None or _ns(msg.header.stamp) >= published[0]:
                            published = (_ns(msg.header.stamp), steps)
                    if level_of(st) == ERROR_LEVEL:
                        t = conversions.stamp_to_s(msg.header.stamp)
                        errors.append((t, st.name, st.message))
                        if st.name.endswith('collision') and collision is None:
                            values = {kv.key: kv.value for kv in st.values}
                            collision = float(values.get('time_s', t))
            else:
                latest[topic] = msg  # latched topics: the newest plan counts
    finally:
        reader.close()
    if not odom:
        raise ValueError(f'bag {bag_dir}: no odometry (topic odom) recorded')
    odom.sort(key=lambda x: x[0])
    flight = Flight(
        odom_t=np.array([o[0] for o in odom]),
        position=np.array([o[1].position for o in odom]),
        velocity=np.array([o[1].velocity for o in odom]),
        euler=rotations.to_euler(np.array([o[1].quaternion for o in odom])),
        collision_time_s=collision, errors=errors, odom_stamps_ns=np.array([o[2] for o in odom], dtype=np.int64),
        clock_stamps_ns=np.array(sorted(clock), dtype=np.int64), sim_published=published,
        truncated=None if repair is None else repair.as_dict())
    if TRAJECTORY in latest:
        flight.traj_start_s, flight.trajectory = conversions.msg_to_sampled(latest[TRAJECTORY])
    if WAYPOINTS in latest:
        flight.waypoints = np.array([conversions.vec3(p.pose.position) for p in latest[WAYPOINTS].poses])
    if MARKERS in latest:
        markers = latest[MARKERS].markers
        flight.obstacles = [(conversions.vec3(m.pose.position), conversions.vec3(m.scale))
                            for m in markers if m.ns == 'obstacles']
        if not len(flight.waypoints):
            flight.waypoints = np.array([conversions.vec3(m.pose.position) for m in markers if m.ns == 'waypoints'])
    if cmds:
        cmds.sort(key=lambda x: x[0])
        flight.cmd_t = np.array([c[0] for c in cmds])
        flight.cmd_specific_force = np.array([c[1] for c in cmds])
        flight.cmd_euler = rotations.to_euler(np.array([c[2] for c in cmds]))
    return flight


def _ns(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


# --- metrics -------------------------------------------------------------------------------------

def record_check(flight: Flight, published_steps: int | None = None) -> dict:
    """The bag against the simulator's own count (module docstring): steps published, distinct stamps recorded
    up to the count's stamp, what is missing, and the odometry gaps."""
    odom = np.unique(flight.odom_stamps_ns)
    clock = np.unique(flight.clock_stamps_ns)
    upto = None
    if published_steps is not None:
        upto = None  # fly's final count: everything the simulator published
    elif flight.sim_published is not None:
        upto, published_steps = flight.sim_published
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


def compute_metrics(flight: Flight, rule: Completion = Completion(), published_steps: int | None = None) -> dict:
    if flight.trajectory is None:
        raise ValueError('bag has no trajectory message (topic trajectory): nothing to compare the flight with')
    t0 = flight.traj_start_s
    t_done = completion_time(flight, rule)
    t_end = t_done if t_done is not None else float(flight.odom_t[-1])
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
        'collided': collided,
        'collision_time_s': None if not collided else flight.collision_time_s - t0,
        'final_error_m': float(np.linalg.norm(flight.position[-1] - final)),
        'max_speed_mps': float(np.max(np.linalg.norm(flight.velocity[window], axis=1))),
        'max_tilt_deg': float(np.degrees(np.max(np.arccos(np.clip(
            np.cos(flight.euler[window, 0]) * np.cos(flight.euler[window, 1]), -1, 1))))),
        'n_waypoints': int(len(waypoints)),
        'n_odometry': int(np.count_nonzero(window)),
        'errors': [f'{t - t0:.2f} s {name}: {message}' for t, name, message in flight.errors[:10]],
        'completion_rule': {'position_tolerance_m': rule.position_tolerance_m,
                            'speed_tolerance_mps': rule.speed_tolerance_mps},
        'record': record_check(flight, published_steps),
        'bag_truncated': flight.truncated,
    }
    return metrics


# --- tables ---------------------------------------------------------------------------------------

TABLE_COLUMNS = [
    ('time_planned_s', 'Time planned (s)', '{:.2f}'), ('time_actual_s', 'Time actual (s)', '{:.2f}'),
    ('length_planned_m', 'Len. planned (m)', '{:.3f}'), ('length_actual_m', 'Len. actual (m)', '{:.3f}'),
    ('avg_velocity_mps', 'Avg. velocity (m/s)', '{:.3f}'), ('rmse_m', 'RMSE (m)', '{:.4f}'),
    ('max_error_m', 'Max error (m)', '{:.4f}'), ('waypoint_miss_max_m', 'Waypoint miss max (m)', '{:.4f}'),
    ('completed', 'Completed', '{}'), ('collided', 'Collided', '{}'),
]


def metrics_table(metrics: dict) -> str:
    """The seed's Table 1/2 columns plus errors, as a markdown table (also what `fly` prints)."""
    head = '| ' + ' | '.join(title for _, title, _ in TABLE_COLUMNS) + ' |'
    rule = '|' + '|'.join('---:' for _ in TABLE_COLUMNS) + '|'
    row = '| ' + ' | '.join(fmt.format(metrics[key]) for key, _, fmt in TABLE_COLUMNS) + ' |'
    return '\n'.join([head, rule, row])


def report_markdown(metrics: dict, figures: list[str], title: str) -> str:
    lines = [f'# {title}', '']
    info = {k: metrics[k] for k in ('mission', 'controller', 'speed_mps', 'outcome') if k in metrics}
    lines += [f'- {k}: {v}' for k, v in info.items()]
    lines += ['', '## Table (the seed\'s Table 1/2 columns and errors)', '', metrics_table(metrics), '',
              f'Completion: within {metrics["completion_rule"]["position_tolerance_m"]} m of the final waypoint at '
              f'speed <= {metrics["completion_rule"]["speed_tolerance_mps"]} m/s. Time actual - planned: '
              f'{metrics["time_over_s"]:.3f} s; final error {metrics["final_error_m"]:.4f} m; max speed '
              f'{metrics["max_speed_mps"]:.2f} m/s; max tilt {metrics["max_tilt_deg"]:.1f} deg.', '']
    lines += ['## Record', '', record_summary(metrics['record']), '']
    if metrics.get('bag_truncated'):
        lines += [truncation_summary(metrics['bag_truncated']), '']
    if metrics['errors']:
        lines += ['## Errors reported on diagnostics', ''] + [f'- {e}' for e in metrics['errors']] + ['']
    lines += ['## Figures', ''] + [f'![{Path(f).stem}]({f})' for f in figures] + ['']
    return '\n'.join(lines)


def truncation_summary(truncated: dict) -> str:
    return (f'bag truncated: {truncated["file"]} was cut at byte {truncated["cut_at_byte"]} of '
            f'{truncated["size_bytes"]} (its recorder did not close it); read up to there from the repaired copy '
            f'{truncated["repaired_copy"]} (the input was not modified)')


def write_report(bag_dir, out_dir, extra: dict | None = None, rule: Completion = Completion(),
                 published_steps: int | None = None, figures: bool = True, flight: Flight | None = None) -> dict:
    """metrics.json, report.md and (figures=True) figures/*.png for the bag; returns the metrics written.
    published_steps: the simulator's final step count, when the caller has it (fly), else the bag's newest.
    flight: the bag's Flight if the caller has loaded it already (load_flight)."""
    out_dir = Path(out_dir)
    flight = load_flight(bag_dir) if flight is None else flight
    metrics = dict(extra or {})
    metrics.update(compute_metrics(flight, rule, published_steps))
    metrics = _json_safe(metrics)
    drawn = draw_figures(flight, out_dir) if figures else []
    write_markdown(metrics, out_dir, drawn)
    (out_dir / 'metrics.json').write_text(json.dumps(metrics, indent=2) + '\n')
    return metrics


def draw_figures(flight: Flight, out_dir) -> list:
    from quad_bringup import report_figures

    return report_figures.draw_all(flight, Path(out_dir) / 'figures')


def write_markdown(metrics: dict, out_dir, figures: list):
    out_dir = Path(out_dir)
    title = f'Flight report: {metrics.get("mission", out_dir.resolve().name)}'
    (out_dir / 'report.md').write_text(
        report_markdown(metrics, [str(Path(f).relative_to(out_dir)) for f in figures], title))


def _json_safe(value):
    """Round floats to what JSON round-trips exactly, so printed metrics == metrics.json."""
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, (np.floating, float)):
        return None if not math.isfinite(value) else float(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value
