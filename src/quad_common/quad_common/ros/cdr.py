"""The lockstep tick's messages as serialized bytes: `odom` (nav_msgs/Odometry) and `cmd/attitude_thrust`
(sensor_msgs/Imu as a setpoint), packed and read with struct, `control/reference` (packed), and `trajectory`
(trajectory_msgs/MultiDOFJointTrajectory) written and read with numpy (a 10,000-point plan in milliseconds instead
of the ~0.3-1 s of building its Python message and converting it point by point).

Why: building these as Python message objects and converting them to and from C cost ~0.1-0.2 ms per message
each way on the 2-core machine, a third of a lockstep tick; Publisher.publish(bytes) and a raw subscription
skip both. The bytes deserialize to exactly what quad_common.conversions builds, and rclpy's bytes decode to
exactly its values (tested; only the padding, which rclpy leaves uninitialised, differs). Input in any
encoding but little-endian plain CDR (another host's byte order, XCDR2) is deserialized the ordinary way.
The layouts were checked against rclpy hot_path.CHECKED_RCLPY_VERSION (test_rclpy_pin.py).
"""

import struct

import numpy as np
from nav_msgs.msg import Odometry
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import Imu
from trajectory_msgs.msg import MultiDOFJointTrajectory

from quad_common import conversions, rotations
from quad_common.cdr_layout import (
    CDR_LE,
    POINT_ALIGNED,
    POINT_UNALIGNED,
    imu_fields,
    imu_setpoint_values,
    le_stamp,
    odometry_fields,
    odometry_state_values,
    trajectory_fields,
    trajectory_points_to_sampled,
)
from quad_common.conversions import BODY_FRAME, UNSET_COVARIANCE, WORLD_FRAME
from quad_common.sampled_trajectory import SampledTrajectory
from quad_common.types import AttitudeSetpoint, Reference, State


def _constant(parts) -> bytes:
    """The fixed bytes after the header stamp (body offset 8): strings (frame ids, names) and uint32 sequence
    lengths, each 4-aligned, padded to the 8-byte alignment of the doubles that follow."""
    out = b''
    for part in parts:
        out += b'\x00' * (-len(out) % 4)
        out += struct.pack('<I', part) if isinstance(part, int) else (
            struct.pack('<I', len(part) + 1) + part.encode() + b'\x00')
    return out + b'\x00' * (-(8 + len(out)) % 8)


def _floats(values):
    """A vector's values as Python floats: an array's tolist() (map(float, array) makes a numpy scalar of each
    first, ~2 us of the ~4 us of a setpoint's packing); the same doubles."""
    return values.tolist() if isinstance(values, np.ndarray) else map(float, values)


def _le_stamp_ns(raw: bytes) -> int | None:
    """header.stamp of a serialized message in nanoseconds; None if it is not little-endian plain CDR."""
    stamp = le_stamp(raw)
    return None if stamp is None else stamp[0] * 1_000_000_000 + stamp[1]


class OdometryPacker:
    """conversions.state_to_odometry as bytes (zero covariances)."""

    def __init__(self, frame_id=WORLD_FRAME, child_frame_id=BODY_FRAME):
        frames = _constant((frame_id, child_frame_id))
        self._struct = struct.Struct(f'<4siI{len(frames)}s7d288x6d288x')
        self._frames = frames

    def pack(self, state: State, time_ns: int) -> bytes:
        q = state.quaternion.tolist()
        return self._struct.pack(CDR_LE, time_ns // 1_000_000_000, time_ns % 1_000_000_000, self._frames,
                                 *state.position.tolist(), *q,
                                 *rotations.rotate_back(q, state.velocity.tolist()), *state.body_rates.tolist())


def odometry_to_state(raw: bytes) -> tuple[int, State]:
    """(header.stamp in ns, conversions.odometry_to_state) of a serialized nav_msgs/Odometry."""
    fields = odometry_fields(raw)
    if fields is None:
        msg = deserialize_message(raw, Odometry)
        return _msg_stamp_ns(msg), conversions.odometry_to_state(msg)
    sec, nanosec, v = fields
    return sec * 1_000_000_000 + nanosec, conversions.odometry_values_to_state(*odometry_state_values(v))


class SetpointPacker:
    """conversions.setpoint_to_imu as bytes."""

    def __init__(self, frame_id=BODY_FRAME):
        frames = _constant((frame_id,))
        self._struct = struct.Struct(f'<4siI{len(frames)}s4d72x3dd64x3d72x')
        self._frames = frames

    def pack(self, setpoint: AttitudeSetpoint, time_ns: int) -> bytes:
        rates, rates_cov0 = setpoint.body_rates, 0.0
        if rates is None:
            rates, rates_cov0 = (0.0, 0.0, 0.0), UNSET_COVARIANCE
        return self._struct.pack(CDR_LE, time_ns // 1_000_000_000, time_ns % 1_000_000_000, self._frames,
                                 *_floats(setpoint.quaternion), *_floats(rates), rates_cov0,
                                 0.0, 0.0, float(setpoint.specific_force_mps2))


class ImuPacker:
    """A measured sensor_msgs/Imu as bytes (mavlink_bridge's `imu`): orientation, or none (its covariance[0] =
    UNSET_COVARIANCE, orientation the identity), rates and specific force; every other covariance zero."""

    def __init__(self, frame_id=BODY_FRAME):
        frames = _constant((frame_id,))
        self._struct = struct.Struct(f'<4siI{len(frames)}s4dd64x3d72x3d72x')
        self._frames = frames

    def pack(self, orientation_xyzw, rates, specific_force, time_ns: int) -> bytes:
        q, cov0 = (orientation_xyzw, 0.0) if orientation_xyzw is not None else ((0.0, 0.0, 0.0, 1.0),
                                                                                UNSET_COVARIANCE)
        return self._struct.pack(CDR_LE, time_ns // 1_000_000_000, time_ns % 1_000_000_000, self._frames,
                                 *_floats(q), cov0, *_floats(rates), *_floats(specific_force))


class ReferencePacker:
    """conversions.reference_to_msg as bytes (`control/reference`: one point, one transform, velocity and
    acceleration; time_from_start 0)."""

    def __init__(self, frame_id=WORLD_FRAME, joint_name=BODY_FRAME):
        head = _constant((frame_id, 1, joint_name, 1, 1))  # joint_names[1], points[1], transforms[1]
        self._struct = struct.Struct(f'<4siI{len(head)}s7dI4x6dI4x6diI')
        self._head = head

    def pack(self, ref: Reference, time_ns: int) -> bytes:
        return self._struct.pack(CDR_LE, time_ns // 1_000_000_000, time_ns % 1_000_000_000, self._head,
                                 *_floats(ref.position), *rotations.from_yaw(ref.yaw).tolist(),
                                 1, *_floats(ref.velocity), 0.0, 0.0, float(ref.yaw_rate),
                                 1, *_floats(ref.acceleration), 0.0, 0.0, 0.0, 0, 0)


def imu_to_setpoint(raw: bytes) -> AttitudeSetpoint:
    """conversions.imu_to_setpoint of a serialized sensor_msgs/Imu (ValueError naming the field)."""
    fields = imu_fields(raw)
    if fields is None:
        return conversions.imu_to_setpoint(deserialize_message(raw, Imu))
    return conversions.imu_values_to_setpoint(*imu_setpoint_values(fields[2]))


def header_stamp_ns(raw: bytes, msg_type) -> int:
    """header.stamp in ns of a serialized message of any stamped type (deserialized if not plain CDR LE)."""
    stamp = _le_stamp_ns(raw)
    return _msg_stamp_ns(deserialize_message(raw, msg_type)) if stamp is None else stamp


def _msg_stamp_ns(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def sampled_to_trajectory(traj: SampledTrajectory, frame_id=WORLD_FRAME, joint_name=BODY_FRAME) -> bytearray:
    """conversions.sampled_to_msg serialized (little-endian plain CDR) with header.stamp 0 (set_stamp stamps it):
    the points written as one structured array in the layout trajectory_to_sampled reads, not point by point."""
    head = b''   # header.frame_id, joint_names, the number of points: each 4-aligned, no padding after
    for part in (frame_id, 1, joint_name, len(traj.times_s)):
        head += b'\x00' * (-len(head) % 4)
        head += struct.pack('<I', part) if isinstance(part, int) else (
            struct.pack('<I', len(part) + 1) + part.encode() + b'\x00')
    n = len(traj.times_s)
    unaligned = (8 + len(head)) % 8 != 0   # the first point's body offset: 4 past an 8-alignment
    points = np.zeros(n, POINT_ALIGNED)
    t_ns = np.round((traj.times_s - traj.times_s[0]) * 1e9).astype(np.int64)
    points['n_tf'] = points['n_vel'] = points['n_acc'] = 1
    points['tf'][:, :3] = traj.position[:, :3]
    points['tf'][:, 3:7] = rotations.from_yaw(traj.position[:, 3])
    points['vel'][:, :3], points['vel'][:, 5] = traj.velocity[:, :3], traj.velocity[:, 3]
    points['acc'][:, :3], points['acc'][:, 5] = traj.acceleration[:, :3], traj.acceleration[:, 3]
    points['sec'], points['nanosec'] = t_ns // 1_000_000_000, t_ns % 1_000_000_000
    raw = bytearray(CDR_LE + bytes(8) + head)
    if unaligned and n:
        first = np.zeros(1, POINT_UNALIGNED)
        for name in POINT_ALIGNED.names:
            first[name] = points[name][:1]
        raw += first.tobytes()
        points = points[1:]
    raw += points.tobytes()
    return raw


def set_stamp(raw: bytearray, stamp) -> bytearray:
    """header.stamp (a builtin_interfaces Time) of a serialized little-endian message, in place."""
    struct.pack_into('<iI', raw, 4, stamp.sec, stamp.nanosec)
    return raw


def trajectory_to_sampled(raw: bytes) -> tuple[int, SampledTrajectory]:
    """(header.stamp in ns, conversions.msg_to_sampled's interpolant) of a serialized MultiDOFJointTrajectory;
    ValueError as msg_to_sampled (no points, non-finite, times not increasing)."""
    fields = trajectory_fields(raw)
    if fields is None:
        msg = deserialize_message(raw, MultiDOFJointTrajectory)
        return _msg_stamp_ns(msg), conversions.msg_to_sampled(msg)[1]
    sec, nanosec, points = fields
    return sec * 1_000_000_000 + nanosec, trajectory_points_to_sampled(points)
