import math

import numpy as np
import pytest
from sensor_msgs.msg import Imu

from quad_common import conversions as conv
from quad_common import rotations as rot
from quad_common.sampled_trajectory import SampledTrajectory
from quad_common.types import AttitudeSetpoint, State


def test_odometry_twist_is_in_body_frame_and_round_trips():
    q = rot.from_euler(0.0, 0.0, np.pi / 2)
    state = State(position=np.array([1.0, 2.0, 3.0]), velocity=np.array([1.0, 0.0, 0.0]), quaternion=q,
                  body_rates=np.array([0.1, 0.2, 0.3]))
    msg = conv.state_to_odometry(state, conv.s_to_stamp(12.5))
    # flying +x (east) while facing +y (north): the body sees the motion on its right, -y
    assert np.allclose(conv.vec3(msg.twist.twist.linear), [0, -1, 0])
    assert (msg.header.frame_id, msg.child_frame_id) == ('map', 'base_link')
    back = conv.odometry_to_state(msg)
    assert np.allclose(back.velocity, state.velocity) and np.allclose(back.position, state.position)
    assert conv.stamp_to_s(msg.header.stamp) == 12.5


def test_setpoint_round_trip_and_unset_rates():
    sp = AttitudeSetpoint(quaternion=rot.from_euler(0.1, 0, 0), specific_force_mps2=9.81)
    msg = conv.setpoint_to_imu(sp, conv.s_to_stamp(0.0))
    assert msg.angular_velocity_covariance[0] == -1
    back = conv.imu_to_setpoint(msg)
    assert back.body_rates is None and np.allclose(back.quaternion, sp.quaternion)
    sp.body_rates = np.array([0.0, 0.0, 0.5])
    assert np.allclose(conv.imu_to_setpoint(conv.setpoint_to_imu(sp, conv.s_to_stamp(0))).body_rates, [0, 0, 0.5])


def test_setpoint_refuses_nan_thrust_and_zero_quaternion():
    msg = Imu()
    msg.orientation.w = 1.0
    msg.linear_acceleration.z = float('nan')
    with pytest.raises(ValueError, match='linear_acceleration.z'):
        conv.imu_to_setpoint(msg)
    msg = Imu()
    msg.orientation.w = 0.0
    msg.linear_acceleration.z = 9.81
    with pytest.raises(ValueError, match='orientation'):
        conv.imu_to_setpoint(msg)


def test_trajectory_message_round_trip():
    t = np.linspace(0, 1, 11)
    p = np.stack([t, t**2, np.ones_like(t), 0.2 * t], axis=1)
    v = np.stack([np.ones_like(t), 2 * t, 0 * t, 0.2 + 0 * t], axis=1)
    a = np.stack([0 * t, 2 + 0 * t, 0 * t, 0 * t], axis=1)
    msg = conv.sampled_to_msg(SampledTrajectory(t, p, v, a), conv.s_to_stamp(100.0))
    start, back = conv.msg_to_sampled(msg)
    assert start == 100.0 and len(msg.points) == 11
    assert np.allclose(back.position, p) and np.allclose(back.velocity, v) and np.allclose(back.acceleration, a)


@pytest.mark.parametrize('bad', [math.nan, math.inf, -math.inf])
def test_finiteness_of_states_and_setpoints(bad):
    """A non-finite value anywhere is found; finite values whose sum overflows are finite."""
    big = np.array([1e308, 1e308, 1e308])
    assert State(position=big, velocity=big).is_finite()
    assert AttitudeSetpoint(specific_force_mps2=1e308, body_rates=big).is_finite()
    for field in ('position', 'velocity', 'quaternion', 'body_rates'):
        state = State()
        getattr(state, field)[1] = bad
        assert not state.is_finite()
    assert not AttitudeSetpoint(specific_force_mps2=bad).is_finite()
    assert not AttitudeSetpoint(body_rates=np.array([0.0, bad, 0.0])).is_finite()
    assert AttitudeSetpoint(body_rates=None).is_finite()
