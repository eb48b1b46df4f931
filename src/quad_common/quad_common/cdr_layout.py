"""Where the fields lie in little-endian plain CDR bytes of the contract's stamped messages (no rclpy): the rclpy
side (quad_common.ros.cdr) packs and reads the lockstep tick's messages with these, and the report reads a bag's
odometry and setpoints with them instead of deserialising each message into Python objects.

A message body starts after the 4-byte encapsulation header: header.stamp (int32 sec, uint32 nanosec), then
header.frame_id and any further strings (uint32 length with the terminating NUL, 4-aligned), then the doubles,
8-aligned from the body's start."""

import struct

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
