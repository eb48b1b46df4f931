"""Flight report from a rosbag2 bag (no rclpy): the seed's Table 1/2 columns, errors and Figures 1-5.

Reads any rosbag2 bag (MCAP or sqlite3, ours or `ros2 bag record`'s) with `rosbags`,
deserialising with its ROS 2 Jazzy typestore; the messages it yields have the rclpy field names,
so the shared converters of quad_common.conversions read them.

Times are message header stamps (simulated time in lockstep). Definitions (docs/quad_bringup.md):
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
COMMAND, DIAGNOSTICS = 'cmd/attitude_thrust', 'diagnostics'
ERROR_LEVEL = ERROR[0]  # diagnostic_msgs levels are bytes in rclpy, ints from rosbags


@dataclass(frozen=True)
class Completion:
    """The course simulator's completion rule (configurable, per vehicle): the one definition that fly's
    live verdict and the report's time_actual_s both use."""
    position_tolerance_m: float = 0.02
    speed_tolerance_mps: float = 0.03
    settle_s: float = 3.0             # without completion the scored window ends at the plan's end + this
    source: str = 'built-in defaults'

    FIELDS = ('position_tolerance_m', 'speed_tolerance_mps', 'settle_s')

    @classmethod
    def for_vehicle(cls, vehicle=None, **overrides) -> 'Completion':
        """The vehicle's `completion:` (vehicle YAML; fields FIELDS) over the defaults, then the overrides that
        are not None (command-line values). Raises ValueError naming the vehicle, the field and the value."""
        values, sources = {}, []
        given = (getattr(vehicle, 'extra', None) or {}).get('completion') if vehicle is not None else None
        if given is not None:
            if not isinstance(given, dict) or set(given) - set(cls.FIELDS):
                raise ValueError(f'vehicle {vehicle.name}: completion = {given!r} may only hold '
                                 f'{", ".join(cls.FIELDS)}')
            values.update(given)
            sources.append(f'vehicle {vehicle.name}')
        chosen = {k: v for k, v in overrides.items() if v is not None}
        if set(chosen) - set(cls.FIELDS):
            raise ValueError(f'completion: unknown field {sorted(set(chosen) - set(cls.FIELDS))[0]!r}')
        values.update(chosen)
        if chosen:
            sources.append('command line')
        for key, value in values.items():
            where = f'vehicle {vehicle.name}: completion.{key}' if key not in chosen else key
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                    or value < 0 or (value == 0 and key != 'settle_s'):
                raise ValueError(f'{where} = {value!r} must be a finite number > 0' +
                                 (' (>= 0 for settle_s)' if key == 'settle_s' else ''))
        return cls(**{k: float(v) for k, v in values.items()}, source=' + '.join(sources) or 'built-in defaults')

    def describe(self) -> dict:
        return {'position_tolerance_m': self.position_tolerance_m, 'speed_tolerance_mps': self.speed_tolerance_mps,
                'settle_s': self.settle_s, 'source': self.source}

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


def _namespaced(topic: str, wanted: str) -> bool:
    """'odom' matches 'odom', '/odom' and '/uav1/odom' (a namespaced flight)."""
    return topic.lstrip('/') == wanted or topic.endswith('/' + wanted)


def load_flight(bag_dir) -> Flight:
    """Extract a Flight from a bag; raises ValueError naming what is missing."""
    ts = typestore()
    odom, cmds, latest = [], [], {}
    errors, collision = [], None
    reader = open_bag_reader(bag_dir)
    try:
        wanted = (ODOM, TRAJECTORY, WAYPOINTS, MARKERS, COMMAND, DIAGNOSTICS)
        connections = [c for c in reader.connections if any(_namespaced(c.topic, w) for w in wanted)]
        for conn, _, raw in reader.messages(connections=connections):
            msg = ts.deserialize_cdr(raw, conn.msgtype)
            topic = next(w for w in wanted if _namespaced(conn.topic, w))
            if topic == ODOM:
                odom.append((conversions.stamp_to_s(msg.header.stamp), conversions.odometry_to_state(msg)))
            elif topic == COMMAND:
                cmds.append((conversions.stamp_to_s(msg.header.stamp), msg.linear_acceleration.z,
                             conversions.quat(msg.orientation)))
            elif topic == DIAGNOSTICS:
                for st in msg.status:
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
        odom_t=np.array([t for t, _ in odom]),
        position=np.array([s.position for _, s in odom]),
        velocity=np.array([s.velocity for _, s in odom]),
        euler=rotations.to_euler(np.array([s.quaternion for _, s in odom])),
        collision_time_s=collision, errors=errors)
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


# --- metrics -------------------------------------------------------------------------------------

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


def compute_metrics(flight: Flight, rule: Completion = Completion()) -> dict:
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
        'collided': collided,
        'collision_time_s': None if not collided else flight.collision_time_s - t0,
        'final_error_m': float(np.linalg.norm(flight.position[-1] - final)),
        'max_speed_mps': float(np.max(np.linalg.norm(flight.velocity[window], axis=1))),
        'max_tilt_deg': float(np.degrees(np.max(np.arccos(np.clip(
            np.cos(flight.euler[window, 0]) * np.cos(flight.euler[window, 1]), -1, 1))))),
        'n_waypoints': int(len(waypoints)),
        'n_odometry': int(np.count_nonzero(window)),
        'errors': [f'{t - t0:.2f} s {name}: {message}' for t, name, message in flight.errors[:10]],
        'completion_rule': rule.describe(),
        'scored_window': {'start_s': 0.0, 'end_s': t_end - t0, 'ends_at': ends_at,
                          'bag_end_s': float(flight.odom_t[-1]) - t0},
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
              f'speed <= {metrics["completion_rule"]["speed_tolerance_mps"]} m/s '
              f'({metrics["completion_rule"].get("source", "built-in defaults")}). '
              f'{_scored_text(metrics)} Time actual - planned: '
              f'{metrics["time_over_s"]:.3f} s; final error {metrics["final_error_m"]:.4f} m; max speed '
              f'{metrics["max_speed_mps"]:.2f} m/s; max tilt {metrics["max_tilt_deg"]:.1f} deg.', '']
    if metrics['errors']:
        lines += ['## Errors reported on diagnostics', ''] + [f'- {e}' for e in metrics['errors']] + ['']
    lines += ['## Figures', ''] + [f'![{Path(f).stem}]({f})' for f in figures] + ['']
    return '\n'.join(lines)


def _scored_text(metrics: dict) -> str:
    w = metrics.get('scored_window')
    if not w:
        return ''
    return (f'Scored window (RMSE, max error, lengths): the plan\'s start to {w["end_s"]:.2f} s, ending at '
            f'{w["ends_at"]}; the bag runs to {w["bag_end_s"]:.2f} s.')


def write_report(bag_dir, out_dir, extra: dict | None = None, rule: Completion = Completion()) -> dict:
    """metrics.json, report.md and figures/*.png for the bag; returns the metrics written."""
    from quad_bringup import report_figures

    out_dir = Path(out_dir)
    flight = load_flight(bag_dir)
    metrics = dict(extra or {})
    metrics.update(compute_metrics(flight, rule))
    metrics = _json_safe(metrics)
    figures = report_figures.draw_all(flight, out_dir / 'figures')
    (out_dir / 'metrics.json').write_text(json.dumps(metrics, indent=2) + '\n')
    title = f'Flight report: {metrics.get("mission", out_dir.resolve().name)}'
    (out_dir / 'report.md').write_text(
        report_markdown(metrics, [str(Path(f).relative_to(out_dir)) for f in figures], title))
    return metrics


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
