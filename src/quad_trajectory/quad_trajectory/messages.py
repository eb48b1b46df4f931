"""Messages of the trajectory node's outputs (`trajectory/path`, `trajectory/waypoints`, `trajectory/markers`)
and the reading of a `waypoints` request (nav_msgs/Path). The `trajectory` message itself is built by
quad_common.conversions.sampled_to_msg.
"""

import numpy as np
from geometry_msgs.msg import Point, PoseStamped, Vector3
from nav_msgs.msg import Path
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from quad_common import rotations
from quad_common.conversions import quat, to_quaternion

WAYPOINT_DIAMETER_M = 0.08


def poses_to_path(positions, yaw, stamp, frame_id) -> Path:
    """positions (N, 3), yaw (N,) -> Path with one pose per row."""
    msg = Path()
    msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    for p, y in zip(np.asarray(positions, dtype=float), np.asarray(yaw, dtype=float)):
        pose = PoseStamped()
        pose.header = msg.header
        pose.pose.position = Point(x=float(p[0]), y=float(p[1]), z=float(p[2]))
        pose.pose.orientation = to_quaternion(rotations.from_yaw(float(y)))
        msg.poses.append(pose)
    return msg


def stamp_all(msg, stamp):
    """Every header stamp of a message built unstamped (a trajectory, a Path and its poses, a MarkerArray)."""
    if hasattr(msg, 'header'):
        msg.header.stamp = stamp
    for part in (*getattr(msg, 'poses', ()), *getattr(msg, 'markers', ())):
        part.header.stamp = stamp


def path_to_waypoints(msg: Path):
    """(positions (N, 3), yaw (N,) or None). Yaw is None when no pose carries an orientation
    (all quaternions zero, the message default), so the node's yaw setting applies."""
    positions = np.array([[p.pose.position.x, p.pose.position.y, p.pose.position.z] for p in msg.poses]).reshape(-1, 3)
    q = np.array([quat(p.pose.orientation) for p in msg.poses]).reshape(-1, 4)
    if len(q) == 0 or np.all(q == 0.0):
        return positions, None
    norms = np.linalg.norm(q, axis=1)
    bad = np.nonzero(~np.isfinite(norms) | (norms < 1e-9))[0]
    if bad.size:
        raise ValueError(f'waypoints.poses[{bad[0]}].pose.orientation = {q[bad[0]].tolist()} is not a rotation')
    return positions, np.array([rotations.to_euler(qi / n)[2] for qi, n in zip(q, norms)])


def _marker(ns, marker_id, kind, stamp, frame_id, position, scale, rgba) -> Marker:
    m = Marker(ns=ns, id=marker_id, type=kind, action=Marker.ADD)
    m.header.stamp = stamp
    m.header.frame_id = frame_id
    m.pose.position = Point(x=float(position[0]), y=float(position[1]), z=float(position[2]))
    m.pose.orientation.w = 1.0
    m.scale = Vector3(x=float(scale[0]), y=float(scale[1]), z=float(scale[2]))
    m.color = ColorRGBA(r=float(rgba[0]), g=float(rgba[1]), b=float(rgba[2]), a=float(rgba[3]))
    return m


def plan_markers(waypoints, world, path_positions, stamp, frame_id) -> MarkerArray:
    """DELETEALL, then namespace `waypoints` (a SPHERE per waypoint), `obstacles` (a CUBE per world block:
    pose = box centre, scale = box size) and `path` (one LINE_STRIP of the planned positions)."""
    out = MarkerArray()
    clear = Marker(action=Marker.DELETEALL)
    clear.header.stamp, clear.header.frame_id = stamp, frame_id
    out.markers.append(clear)
    for i, p in enumerate(np.asarray(waypoints)):
        out.markers.append(_marker('waypoints', i, Marker.SPHERE, stamp, frame_id, p, [WAYPOINT_DIAMETER_M] * 3,
                                   (1.0, 0.5, 0.0, 1.0)))
    blocks = world.blocks if world is not None else np.zeros((0, 6))
    for i, b in enumerate(blocks):
        lo, hi = b[0::2], b[1::2]
        out.markers.append(_marker('obstacles', i, Marker.CUBE, stamp, frame_id, (lo + hi) / 2, hi - lo,
                                   (0.5, 0.5, 0.5, 0.6)))
    line = _marker('path', 0, Marker.LINE_STRIP, stamp, frame_id, (0.0, 0.0, 0.0), (0.02, 0.0, 0.0),
                   (0.0, 0.6, 1.0, 1.0))
    line.points = [Point(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in np.asarray(path_positions)]
    out.markers.append(line)
    return out
