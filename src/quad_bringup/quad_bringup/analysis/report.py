"""Flight report from a rosbag2 bag (no rclpy): the seed's Table 1/2 columns, errors and Figures 1-5.

Reads any rosbag2 bag (MCAP or sqlite3, ours or `ros2 bag record`'s) with `rosbags`,
deserialising with its ROS 2 Jazzy typestore; the messages it yields have the rclpy field names,
so the shared converters of quad_common.conversions read them. Odometry, setpoints, /clock and the plan, most of a
bag, are read from their bytes where they are little-endian plain CDR (quad_common.cdr_layout: the same values,
without a Python object per field), and deserialised like the rest where not.

Times are message header stamps (simulated time in lockstep). The metrics and their definitions (the scored
window, completion per vehicle) are quad_bringup.analysis.metrics (numpy only; docs/quad_bringup.md).
"""

import json
import math
from pathlib import Path
from typing import NamedTuple

import numpy as np

from quad_bringup.analysis.metrics import (  # noqa: F401  (re-exported: the report's API)
    Completion,
    Flight,
    arc_length,
    closest_approach,
    completion_time,
    compute_metrics,
    planned_position,
    record_check,
    record_summary,
)
from quad_bringup.recording.recorder import open_bag_reader, typestore
from quad_common import contract, conversions, rotations
from quad_common.cdr_layout import (
    imu_fields,
    imu_setpoint_values,
    le_stamp,
    odometry_fields,
    odometry_state_values,
    trajectory_fields,
    trajectory_points_to_sampled,
)
from quad_common.contract import DIAGNOSTICS, ENGAGED, ODOM, TRAJECTORY
from quad_common.contract import SETPOINT as COMMAND
from quad_common.contract import TRAJECTORY_MARKERS as MARKERS
from quad_common.contract import TRAJECTORY_WAYPOINTS as WAYPOINTS
from quad_common.diagnostics import ERROR, level_of

ERROR_LEVEL = ERROR[0]  # diagnostic_msgs levels are bytes in rclpy, ints from rosbags
CLOCK = contract.CLOCK
HANDOVER_KEY = 'handover'   # the bridge's setpoints status: the hand-over phase (quad_bridge.handover)


_namespaced = contract.matches


WANTED = (ODOM, TRAJECTORY, WAYPOINTS, MARKERS, COMMAND, DIAGNOSTICS, CLOCK, ENGAGED)   # what a Flight is made of
# topic -> (its type, the reader of its fields from the bytes)
FROM_BYTES = {ODOM: ('nav_msgs/msg/Odometry', odometry_fields), COMMAND: ('sensor_msgs/msg/Imu', imu_fields),
              CLOCK: ('rosgraph_msgs/msg/Clock', le_stamp),   # a Clock's body is its one Time
              TRAJECTORY: ('trajectory_msgs/msg/MultiDOFJointTrajectory', trajectory_fields)}


def load_flight(bag_dir, namespace: str = '') -> Flight:
    """Extract a Flight from a bag; raises ValueError naming what is missing. namespace: one fleet vehicle's
    flight (its topics under /NAMESPACE/, and /clock) from a fleet's bag."""
    return load_flights(bag_dir, (namespace,))[namespace]


def load_flights(bag_dir, namespaces) -> dict:
    """{namespace: its Flight} (load_flight's) from one read of the bag: a fleet's N vehicles open, index and
    deserialize it once, not N times (opening parses its metadata and every connection's QoS: ~1 s for a
    16-vehicle bag)."""
    parts = {ns: _FlightParts() for ns in namespaces}
    reader, repair = open_bag_reader(bag_dir)
    try:
        routes = {}      # connection id -> [(its vehicle's parts, the contract topic it is)]
        for conn in reader.connections:
            routes[conn.id] = []
            for ns in namespaces:
                topic = next((w for w in WANTED if _is(conn.topic, w, ns)), None)
                if topic is not None:
                    routes[conn.id].append((parts[ns], topic))
        connections = [c for c in reader.connections if routes[c.id]]
        if not connections:   # (rosbags reads every connection when given none)
            where = ', '.join(f'/{ns}/' for ns in namespaces if ns)
            raise ValueError(f'bag {bag_dir}: none of the flight topics (odom, trajectory, cmd/attitude_thrust'
                             f'{f" under {where}" if where else ""}) in it')
        from_bytes = {}   # connection id -> the reader of its fields (one contract topic of the right type), or None
        for conn in connections:
            topics = {topic for _, topic in routes[conn.id]}
            kind = FROM_BYTES.get(topics.pop()) if len(topics) == 1 else None
            from_bytes[conn.id] = kind[1] if kind is not None and kind[0] == conn.msgtype else None
        ts = typestore(*(c.msgtype for c in connections))
        for conn, record_ns, raw in reader.messages(connections=connections):
            fields = from_bytes[conn.id](raw) if from_bytes[conn.id] is not None else None
            msg = ts.deserialize_cdr(raw, conn.msgtype) if fields is None else None
            for part, topic in routes[conn.id]:
                part.add(topic, msg, record_ns, fields)
    finally:
        reader.close()
    return {ns: part.flight(bag_dir, ns, repair) for ns, part in parts.items()}


def _is(topic: str, wanted: str, namespace: str) -> bool:
    """Whether a recorded topic is the contract's `wanted` one (of a fleet vehicle's namespace when given:
    /NAMESPACE/wanted, global topics such as /clock as they are)."""
    if not namespace:
        return _namespaced(topic, wanted)
    return topic == wanted if wanted.startswith('/') else topic == f'/{namespace}/{wanted}'


class _FlightParts:
    """One flight's messages as the bag is read (load_flights), then its Flight."""

    def __init__(self):
        self.odom, self.cmds, self.latest, self.clock, self.engaged, self.handover = [], [], {}, [], [], []
        self.odom_age = []
        self.errors, self.collision, self.published = [], None, None

    def add(self, topic: str, msg, record_ns: int, fields=None):
        """msg: the deserialised message, or None where `fields` holds its stamp and values (FROM_BYTES)."""
        if topic == ODOM:
            if fields is None:
                stamp, state = msg.header.stamp, conversions.odometry_to_state(msg)
            else:
                stamp = _Stamp(fields[0], fields[1])
                state = conversions.odometry_values_to_state(*odometry_state_values(fields[2]))
            self.odom.append((conversions.stamp_to_s(stamp), state, _ns(stamp), record_ns))
        elif topic == CLOCK:
            self.clock.append(_ns(msg.clock if fields is None else _Stamp(*fields)))
        elif topic == COMMAND:
            try:  # the contract's one decoder; a setpoint it refuses was refused by the vehicle too
                if fields is None:
                    stamp, setpoint = msg.header.stamp, conversions.imu_to_setpoint(msg)
                else:
                    stamp = _Stamp(fields[0], fields[1])
                    setpoint = conversions.imu_values_to_setpoint(*imu_setpoint_values(fields[2]))
            except ValueError:
                return
            self.cmds.append((conversions.stamp_to_s(stamp), setpoint.specific_force_mps2, setpoint.quaternion,
                              record_ns))
        elif topic == ENGAGED:
            self.engaged.append((record_ns, bool(msg.data)))
        elif topic == DIAGNOSTICS:
            for st in msg.status:
                values = {kv.key: kv.value for kv in st.values}
                phase = values.get(HANDOVER_KEY)
                if phase is not None:
                    self.handover.append((record_ns, phase))
                age_ms = values.get(contract.CONTROLLER_ODOM_AGE_MS, 'None')
                if st.name == contract.CONTROLLER_STATUS and age_ms != 'None':
                    self.odom_age.append((record_ns, float(age_ms)))
                if st.name == contract.SIM_PUBLISHED:
                    steps = int(values.get('steps', -1))
                    if self.published is None or _ns(msg.header.stamp) >= self.published[0]:
                        self.published = (_ns(msg.header.stamp), steps)
                if level_of(st) == ERROR_LEVEL:
                    t = conversions.stamp_to_s(msg.header.stamp)
                    self.errors.append((t, st.name, st.message))
                    if self.collision is None:  # an event is a key, not a name or a message
                        self.collision = contract.event_time_s(values, contract.COLLISION_TIME_S)
        else:   # latched topics: the newest plan counts (the plan: its message, or its stamp and points' fields)
            self.latest[topic] = msg if fields is None else fields

    def flight(self, bag_dir, namespace: str, repair) -> Flight:
        odom, cmds, latest, clock = self.odom, self.cmds, self.latest, self.clock
        if not odom:
            raise ValueError(f'bag {bag_dir}: no odometry (topic {f"/{namespace}/" if namespace else ""}odom) '
                             'recorded')
        odom.sort(key=lambda x: x[0])
        published, collision = self.published, self.collision
        flight = Flight(
            odom_t=np.array([o[0] for o in odom]),
            position=np.array([o[1].position for o in odom]),
            velocity=np.array([o[1].velocity for o in odom]),
            euler=rotations.to_euler(np.array([o[1].quaternion for o in odom])),
            collision_time_s=collision, errors=self.errors,
            odom_stamps_ns=np.array([o[2] for o in odom], dtype=np.int64),
            odom_record_ns=np.array([o[3] for o in odom], dtype=np.int64),
            clock_stamps_ns=np.array(sorted(clock), dtype=np.int64), sim_published=published,
            collisions_known=bool(clock) or published is not None or collision is not None,   # a simulator's bag
            truncated=None if repair is None else repair.as_dict(), engaged=sorted(self.engaged),
            handover=sorted(self.handover), controller_odom_age=sorted(self.odom_age))
        if TRAJECTORY in latest:
            plan = latest[TRAJECTORY]
            if isinstance(plan, tuple):   # trajectory_fields: (sec, nanosec, points)
                flight.traj_start_s = conversions.stamp_to_s(_Stamp(plan[0], plan[1]))
                flight.trajectory = trajectory_points_to_sampled(plan[2])
            else:
                flight.traj_start_s, flight.trajectory = conversions.msg_to_sampled(plan)
        if WAYPOINTS in latest:
            flight.waypoints = np.array([conversions.vec3(p.pose.position) for p in latest[WAYPOINTS].poses])
        if MARKERS in latest:
            markers = latest[MARKERS].markers
            flight.obstacles = [(conversions.vec3(m.pose.position), conversions.vec3(m.scale))
                                for m in markers if m.ns == 'obstacles']
            if not len(flight.waypoints):
                flight.waypoints = np.array([conversions.vec3(m.pose.position) for m in markers
                                             if m.ns == 'waypoints'])
        if cmds:
            cmds.sort(key=lambda x: x[0])
            flight.cmd_t = np.array([c[0] for c in cmds])
            flight.cmd_specific_force = np.array([c[1] for c in cmds])
            flight.cmd_euler = rotations.to_euler(np.array([c[2] for c in cmds]))
            flight.cmd_record_ns = np.array([c[3] for c in cmds], dtype=np.int64)
        return flight


class _Stamp(NamedTuple):
    """builtin_interfaces/Time's fields, as read from the bytes."""
    sec: int
    nanosec: int


def _ns(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


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
    row = '| ' + ' | '.join('n/a' if metrics[key] is None else fmt.format(metrics[key])
                            for key, _, fmt in TABLE_COLUMNS) + ' |'
    return '\n'.join([head, rule, row])


def report_markdown(metrics: dict, figures: list[str], title: str) -> str:
    lines = [f'# {title}', '']
    info = {k: metrics[k] for k in ('mission', 'controller', 'speed_mps', 'outcome') if k in metrics}
    if info.get('speed_mps', 0) is None:   # no --speed: the mission's own speed profile was flown
        info['speed_mps'] = "the mission's (no --speed)"
    lines += [f'- {k}: {v}' for k, v in info.items()]
    lines += ['', '## Table (the seed\'s Table 1/2 columns and errors)', '', metrics_table(metrics), '',
              f'Completion: within {metrics["completion_rule"]["position_tolerance_m"]} m of the final waypoint at '
              f'speed <= {metrics["completion_rule"]["speed_tolerance_mps"]} m/s '
              f'({metrics["completion_rule"].get("source", "built-in defaults")}). '
              f'{_scored_text(metrics)} Time actual - planned: '
              f'{metrics["time_over_s"]:.3f} s{_early_text(metrics)}; final error {metrics["final_error_m"]:.4f} m; '
              f'max speed '
              f'{metrics["max_speed_mps"]:.2f} m/s; max tilt {metrics["max_tilt_deg"]:.1f} deg.', '']
    lines += [_start_text(metrics), '']
    lines += ['## Record', '', record_summary(metrics['record']), '']
    if metrics.get('bag_truncated'):
        lines += [truncation_summary(metrics['bag_truncated']), '']
    if metrics['errors']:
        lines += ['## Errors reported on diagnostics', ''] + [f'- {e}' for e in metrics['errors']] + ['']
    lines += ['## Figures', ''] + [f'![{Path(f).stem}]({f})' for f in figures] + ['']
    return '\n'.join(lines)


def _start_text(metrics: dict) -> str:
    """Where the vehicle was when the plan started (a bridge flight may begin away from it and join it)."""
    offset, tolerance = metrics['start_offset_m'], metrics['completion_rule']['position_tolerance_m']
    line = f'Start: the vehicle was {offset:.3f} m from the plan\'s first point when the plan began.'
    if offset > tolerance:
        line += (f' JOINED: more than the position tolerance ({tolerance} m), so the first errors are the join, not '
                 'the tracking; start the plan where the vehicle hovers (the controller refuses a start farther '
                 'than its max_start_step_m).')
    return line


def _early_text(metrics: dict) -> str:
    """Why time actual can be shorter than time planned."""
    if metrics['time_over_s'] >= 0 or not metrics.get('completed'):
        return ''
    return (' (time actual ends at completion: the vehicle within the position tolerance of the final waypoint '
            'and below the speed tolerance, which the plan\'s slow final approach reaches before its end)')


def _scored_text(metrics: dict) -> str:
    w = metrics.get('scored_window')
    if not w:
        return ''
    return (f'Scored window (RMSE, max error, lengths): the plan\'s start to {w["end_s"]:.2f} s, ending at '
            f'{w["ends_at"]}; the bag runs to {w["bag_end_s"]:.2f} s.')


def truncation_summary(truncated: dict) -> str:
    return (f'bag truncated: {truncated["file"]} was cut at byte {truncated["cut_at_byte"]} of '
            f'{truncated["size_bytes"]} (its recorder did not close it); read up to there from the repaired copy '
            f'{truncated["repaired_copy"]} (the input was not modified)')


def write_report(bag_dir, out_dir, extra: dict | None = None, rule: Completion | None = None,
                 published: tuple | None = None, figures: bool = True, flight: Flight | None = None,
                 figure_parts: int = 1) -> dict:
    """metrics.json, report.md and (figures=True) figures/*.png for the bag, drawn in figure_parts processes
    (report_figures.draw_all); returns the metrics written.
    published: (stamp ns, steps) of the simulator's newest count the caller saw (fly's monitor); the bag's newest
    too (metrics.record_check).
    flight: the bag's Flight if the caller has loaded it already (load_flight)."""
    rule = rule or Completion()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    flight = load_flight(bag_dir) if flight is None else flight
    metrics = dict(extra or {})
    metrics.update(compute_metrics(flight, rule, published))
    metrics = _json_safe(metrics)
    drawn = draw_figures(flight, out_dir, figure_parts) if figures else []
    write_markdown(metrics, out_dir, drawn)
    (out_dir / 'metrics.json').write_text(json.dumps(metrics, indent=2) + '\n')
    return metrics


def draw_figures(flight: Flight, out_dir, parts: int = 1) -> list:
    from quad_bringup.analysis import report_figures

    return report_figures.draw_run(flight, out_dir, parts)


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
