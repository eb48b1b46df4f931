import struct

import numpy as np
import pytest
from nav_msgs.msg import Odometry
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import Imu
from trajectory_msgs.msg import MultiDOFJointTrajectory

from quad_common import conversions as conv
from quad_common import rotations as rot
from quad_common.ros import cdr
from quad_common.types import AttitudeSetpoint, Reference, State

STATE = State(position=np.array([1.5, -2.25, 3.0]), velocity=np.array([0.3, -0.7, 0.2]),
              quaternion=rot.from_euler(0.1, -0.2, 2.5), body_rates=np.array([0.01, -0.5, 3.25]))
TIME_NS = 12_345_678_901


@pytest.mark.parametrize('frames', [('map', 'base_link'), ('', 'x'), ('world_frame', 'uav1/base_link')])
def test_odometry_bytes_are_rclpys_and_decode_to_the_same_state(frames):
    raw = cdr.OdometryPacker(*frames).pack(STATE, TIME_NS)
    msg = conv.state_to_odometry(STATE, conv.s_to_stamp(TIME_NS * 1e-9), *frames)
    assert len(raw) == len(serialize_message(msg)) and deserialize_message(raw, Odometry) == msg
    stamp_ns, state = cdr.odometry_to_state(serialize_message(msg))
    expected = conv.odometry_to_state(msg)
    assert stamp_ns == TIME_NS
    for name in ('position', 'velocity', 'quaternion', 'body_rates'):
        assert np.array_equal(getattr(state, name), getattr(expected, name)), name


@pytest.mark.parametrize('rates', [None, np.array([0.1, -0.2, 0.5])])
def test_setpoint_bytes_are_rclpys_and_decode_to_the_same_setpoint(rates):
    sp = AttitudeSetpoint(quaternion=rot.from_euler(0.2, 0.1, -1.0), specific_force_mps2=10.5, body_rates=rates)
    raw = cdr.SetpointPacker().pack(sp, TIME_NS)
    msg = conv.setpoint_to_imu(sp, conv.s_to_stamp(TIME_NS * 1e-9))
    assert len(raw) == len(serialize_message(msg)) and deserialize_message(raw, Imu) == msg
    assert cdr.header_stamp_ns(raw, Imu) == TIME_NS
    back, expected = cdr.imu_to_setpoint(serialize_message(msg)), conv.imu_to_setpoint(msg)
    assert np.array_equal(back.quaternion, expected.quaternion)
    assert back.specific_force_mps2 == expected.specific_force_mps2
    assert (back.body_rates is None and expected.body_rates is None) or np.array_equal(back.body_rates,
                                                                                        expected.body_rates)


@pytest.mark.parametrize('orientation', [None, rot.from_euler(0.2, 0.1, -1.0)])
def test_imu_bytes_are_rclpys(orientation):
    """The bridge's measured `imu` as bytes: the message it built field by field before."""
    gyro, acc = np.array([0.1, -0.2, 0.5]), np.array([0.3, -0.4, 9.7])
    raw = cdr.ImuPacker().pack(orientation, gyro, acc, TIME_NS)
    msg = Imu()
    msg.header.stamp = conv.s_to_stamp(TIME_NS * 1e-9)
    msg.header.frame_id = conv.BODY_FRAME
    if orientation is None:
        msg.orientation_covariance[0] = conv.UNSET_COVARIANCE
    else:
        msg.orientation = conv.to_quaternion(orientation)
    msg.angular_velocity, msg.linear_acceleration = conv.to_vector3(gyro), conv.to_vector3(acc)
    assert len(raw) == len(serialize_message(msg)) and deserialize_message(raw, Imu) == msg


@pytest.mark.parametrize('frame_id', ['map', '', 'world_frame'])
def test_reference_bytes_are_rclpys(frame_id):
    ref = Reference(position=np.array([1.5, -2.25, 3.0]), velocity=np.array([0.3, -0.7, 0.2]),
                    acceleration=np.array([-1.0, 0.5, 9.0]), jerk=np.array([1.0, 2.0, 3.0]), yaw=2.9, yaw_rate=-0.4)
    raw = cdr.ReferencePacker(frame_id).pack(ref, TIME_NS)
    msg = conv.reference_to_msg(ref, conv.s_to_stamp(TIME_NS * 1e-9), frame_id)
    assert len(raw) == len(serialize_message(msg)) and deserialize_message(raw, MultiDOFJointTrajectory) == msg


def test_setpoint_refusals_name_the_field_as_the_message_path_does():
    msg = Imu()
    msg.orientation.w = 1.0
    msg.linear_acceleration.z = float('nan')
    with pytest.raises(ValueError, match='linear_acceleration.z'):
        cdr.imu_to_setpoint(serialize_message(msg))
    msg = Imu()
    msg.orientation.w = 0.0
    msg.linear_acceleration.z = 9.81
    with pytest.raises(ValueError, match='orientation'):
        cdr.imu_to_setpoint(serialize_message(msg))


def _big_endian_odometry(msg) -> bytes:
    """msg as plain CDR big endian (encapsulation 00 00, another host's byte order), written field by field."""
    def string(text, offset):
        return b'\x00' * (-offset % 4) + struct.pack('>I', len(text) + 1) + text.encode() + b'\x00'
    body = struct.pack('>iI', msg.header.stamp.sec, msg.header.stamp.nanosec)
    body += string(msg.header.frame_id, len(body))
    body += string(msg.child_frame_id, len(body))
    body += b'\x00' * (-len(body) % 8)
    pose, twist = msg.pose.pose, msg.twist.twist
    body += struct.pack('>7d36d', *conv.vec3(pose.position), pose.orientation.x, pose.orientation.y,
                        pose.orientation.z, pose.orientation.w, *msg.pose.covariance)
    body += struct.pack('>6d36d', *conv.vec3(twist.linear), *conv.vec3(twist.angular), *msg.twist.covariance)
    return b'\x00\x00\x00\x00' + body


def test_other_encodings_go_to_rclpy():
    """Anything but plain CDR little endian (here big endian) is not read with the struct layout: rclpy decodes it
    to the same state and stamp."""
    msg = conv.state_to_odometry(STATE, conv.s_to_stamp(1.5))
    big_endian = _big_endian_odometry(msg)
    assert big_endian[:4] != cdr.CDR_LE and deserialize_message(big_endian, Odometry) == msg  # what rclpy reads
    stamp_ns, state = cdr.odometry_to_state(big_endian)
    assert stamp_ns == 1_500_000_000 and cdr.header_stamp_ns(big_endian, Odometry) == 1_500_000_000
    expected = conv.odometry_to_state(msg)
    for name in ('position', 'velocity', 'quaternion', 'body_rates'):
        assert np.array_equal(getattr(state, name), getattr(expected, name)), name


@pytest.mark.parametrize('frame_id', ['map', 'mapp', ''])  # first point 8-aligned, 4 past it, 8-aligned
def test_trajectory_bytes_decode_to_msg_to_sampleds_interpolant(frame_id):
    from quad_common.sampled_trajectory import SampledTrajectory
    rng = np.random.default_rng(3)
    n = 500
    p, v, a = rng.normal(size=(n, 4)), rng.normal(size=(n, 4)), rng.normal(size=(n, 4))
    msg = conv.sampled_to_msg(SampledTrajectory(np.arange(n) * 0.013, p, v, a), conv.s_to_stamp(7.25), frame_id)
    start_s, expected = conv.msg_to_sampled(msg)
    stamp_ns, got = cdr.trajectory_to_sampled(serialize_message(msg))
    assert stamp_ns == 7_250_000_000 and start_s == 7.25
    for name in ('times_s', 'position', 'velocity', 'acceleration'):
        assert np.array_equal(getattr(got, name), getattr(expected, name)), name


@pytest.mark.parametrize('n', [1, 2, 500])
@pytest.mark.parametrize('frame_id', ['map', 'mapp', '', 'world'])  # the first point 8-aligned or 4 past it
def test_trajectory_written_as_bytes_deserializes_to_sampled_to_msgs_message(frame_id, n):
    from quad_common.sampled_trajectory import SampledTrajectory
    rng = np.random.default_rng(n)
    p, v, a = rng.normal(size=(n, 4)), rng.normal(size=(n, 4)), rng.normal(size=(n, 4))
    sampled = SampledTrajectory(0.5 + np.arange(n) * 0.013, p, v, a)
    stamp = conv.s_to_stamp(7.25)
    raw = bytes(cdr.set_stamp(cdr.sampled_to_trajectory(sampled, frame_id), stamp))
    expected = conv.sampled_to_msg(sampled, stamp, frame_id)
    assert deserialize_message(raw, MultiDOFJointTrajectory) == expected
    rclpy_raw = serialize_message(expected)   # the same bytes but for padding, which rclpy leaves unset
    assert len(raw) == len(rclpy_raw)
    assert all(raw[i] == 0 for i in range(len(raw)) if raw[i] != rclpy_raw[i])


def test_trajectory_bytes_refused_as_msg_to_sampled_refuses():
    msg = MultiDOFJointTrajectory()
    with pytest.raises(ValueError, match='no points'):
        cdr.trajectory_to_sampled(serialize_message(msg))
    from quad_common.sampled_trajectory import SampledTrajectory
    p = np.zeros((3, 4))
    msg = conv.sampled_to_msg(SampledTrajectory([0.0, 1.0, 2.0], p, p, p), conv.s_to_stamp(0.0))
    msg.points[1].velocities[0].linear.y = float('nan')
    with pytest.raises(ValueError, match='non-finite'):
        cdr.trajectory_to_sampled(serialize_message(msg))
    msg.points[1].velocities[0].linear.y = 0.0
    msg.points[2].time_from_start.sec = 0
    with pytest.raises(ValueError, match='must increase'):
        cdr.trajectory_to_sampled(serialize_message(msg))
    msg.points[2].velocities = []   # not the fixed layout: read the ordinary way, same rules
    with pytest.raises(ValueError, match='must increase'):
        cdr.trajectory_to_sampled(serialize_message(msg))
