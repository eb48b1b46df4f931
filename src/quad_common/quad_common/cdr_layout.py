"""Where the fields lie in little-endian plain CDR bytes of the contract's stamped messages (no rclpy): the rclpy
side (quad_common.ros.cdr) packs and reads the lockstep tick's messages and the plan with these, and the report reads
a bag's odometry, setpoints and plan with them instead of deserialising each message into Python objects.

A message body starts after the 4-byte encapsulation header: header.stamp (int32 sec, uint32 nanosec), then
header.frame_id and any further strings (uint32 length with the terminating NUL, 4-aligned), then the doubles,
8-aligned from the body's start."""

import struct

import numpy as np

from quad_common import rotations
from quad_common.sampled_trajectory import SampledTrajectory

CDR_LE = b'\x00\x01\x00\x00'  # encapsulation header: plain CDR, little endian
STAMP = struct.Struct('<iI')
ODOM_FIELDS = struct.Struct('<7d288x6d')  # pose, its covariance (36 d), twist; its covariance is not read
IMU_FIELDS = struct.Struct('<4dd64x3dd64x3dd')  # orientation, cov[0], rates, cov[0], acceleration, cov[0]
ODOM_STRINGS, IMU_STRINGS = 2, 1   # header.frame_id and child_frame_id; header.frame_id


def fields_offset(raw: bytes, strings: int) -> int:
    """Offset in raw of the first field after the header's `strings` strings (frame ids)."""
    offset = 8  # from the body's start, after the stamp
    for _ in range(strings):
        offset += -offset % 4
        offset += 4 + struct.unpack_from('<I', raw, 4 + offset)[0]
    return 4 + offset + (-offset % 8)


def le_stamp(raw: bytes) -> tuple[int, int] | None:
    """header.stamp (sec, nanosec) of a serialized message; None if it is not little-endian plain CDR."""
    if raw[:4] != CDR_LE:
        return None
    return STAMP.unpack_from(raw, 4)


def odometry_fields(raw: bytes):
    """(sec, nanosec, (position 3, quaternion x y z w, body velocity 3, body rates 3)) of a serialized
    nav_msgs/Odometry; None if it is not little-endian plain CDR."""
    stamp = le_stamp(raw)
    return None if stamp is None else (*stamp, ODOM_FIELDS.unpack_from(raw, fields_offset(raw, ODOM_STRINGS)))


def imu_fields(raw: bytes):
    """(sec, nanosec, IMU_FIELDS' values) of a serialized sensor_msgs/Imu; None if it is not little-endian plain
    CDR."""
    stamp = le_stamp(raw)
    return None if stamp is None else (*stamp, IMU_FIELDS.unpack_from(raw, fields_offset(raw, IMU_STRINGS)))


def odometry_state_values(v) -> tuple:
    """ODOM_FIELDS' values as conversions.odometry_values_to_state takes them: position, quaternion, body velocity,
    body rates."""
    return v[0:3], v[3:7], v[7:10], v[10:13]


def imu_setpoint_values(v) -> tuple:
    """IMU_FIELDS' values as conversions.imu_values_to_setpoint takes them: orientation and its covariance[0], rates
    and theirs, linear_acceleration.z and its covariance[0]."""
    return v[0:4], v[4], v[5:8], v[8], v[11], v[12]


def _point_dtype(aligned: bool) -> np.dtype:
    """One MultiDOFJointTrajectoryPoint with one transform, one velocity and one acceleration, starting at a body
    offset that is 8-aligned (aligned) or 4 past it: the uint32 sequence lengths, the doubles (8-aligned in the
    body) and time_from_start."""
    offsets = [0, 8, 64, 72, 120, 128, 176, 180] if aligned else [0, 4, 60, 68, 116, 124, 172, 176]
    return np.dtype({'names': ['n_tf', 'tf', 'n_vel', 'vel', 'n_acc', 'acc', 'sec', 'nanosec'],
                     'formats': ['<u4', ('<f8', 7), '<u4', ('<f8', 6), '<u4', ('<f8', 6), '<i4', '<u4'],
                     'offsets': offsets, 'itemsize': 184 if aligned else 180})


POINT_ALIGNED, POINT_UNALIGNED = _point_dtype(True), _point_dtype(False)


def _skip_string(raw: bytes, offset: int) -> int:
    """Body offset after the CDR string at body offset `offset` (4-aligned first)."""
    offset += -offset % 4
    return offset + 4 + struct.unpack_from('<I', raw, 4 + offset)[0]


def _u32(raw: bytes, offset: int) -> tuple[int, int]:
    offset += -offset % 4
    return struct.unpack_from('<I', raw, 4 + offset)[0], offset + 4


def _trajectory_points(raw: bytes):
    """The points of a little-endian plain-CDR MultiDOFJointTrajectory as arrays (transforms, velocities,
    accelerations, time_from_start's sec and nanosec), or None when there is none or a point has other than one
    transform, velocity and acceleration (then it is read the ordinary way)."""
    offset = _skip_string(raw, 8)                       # header.stamp, header.frame_id
    n_names, offset = _u32(raw, offset)
    for _ in range(n_names):
        offset = _skip_string(raw, offset)
    n_points, offset = _u32(raw, offset)
    if n_points == 0:
        return None   # read the ordinary way, which refuses it
    parts = []
    if offset % 8:                                      # the first point starts 4 past an 8-alignment
        if 4 + offset + POINT_UNALIGNED.itemsize > len(raw):
            return None
        parts.append(np.frombuffer(raw, POINT_UNALIGNED, count=1, offset=4 + offset))
        offset, n_points = offset + POINT_UNALIGNED.itemsize, n_points - 1
    if 4 + offset + n_points * POINT_ALIGNED.itemsize > len(raw):
        return None  # shorter points (no velocity, ...): the first that is, has a length other than 1 where read
    parts.append(np.frombuffer(raw, POINT_ALIGNED, count=n_points, offset=4 + offset))
    points = [(p['n_tf'], p['tf'], p['n_vel'], p['vel'], p['n_acc'], p['acc'], p['sec'], p['nanosec'])
              for p in parts]
    n_tf, tf, n_vel, vel, n_acc, acc, sec, nanosec = (np.concatenate(x) for x in zip(*points))
    if not (np.all(n_tf == 1) and np.all(n_vel == 1) and np.all(n_acc == 1)):
        return None
    return tf, vel, acc, sec, nanosec


def trajectory_fields(raw: bytes):
    """(sec, nanosec, its points as _trajectory_points gives them) of a serialized
    trajectory_msgs/MultiDOFJointTrajectory; None if it is not little-endian plain CDR, has no point, or a point
    has other than one transform, velocity and acceleration."""
    stamp = le_stamp(raw)
    points = None if stamp is None else _trajectory_points(raw)
    return None if points is None else (*stamp, points)


def trajectory_points_to_sampled(points) -> SampledTrajectory:
    """conversions.msg_to_sampled's interpolant of trajectory_fields' points (the same values: yaw from each
    rotation, angular.z as the yaw rate and acceleration)."""
    tf, vel, acc, sec, nanosec = points
    t = sec + nanosec * 1e-9
    position = np.column_stack([tf[:, :3], rotations.to_euler(tf[:, 3:7])[:, 2]])
    velocity = np.column_stack([vel[:, :3], vel[:, 5]])
    acceleration = np.column_stack([acc[:, :3], acc[:, 5]])
    return SampledTrajectory(t, position, velocity, acceleration)
