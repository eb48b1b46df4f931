import numpy as np
import pytest

from quad_common import rotations
from quad_common.types import AttitudeSetpoint
from quad_common.vehicle import AttitudeGains
from quad_sim.onboard_attitude import attitude_moments

INERTIA = np.array([1.43e-5, 1.43e-5, 2.89e-5])


def test_zero_at_the_setpoint():
    q = rotations.from_euler(0.1, -0.05, 0.7)
    sp = AttitudeSetpoint(quaternion=q, body_rates=np.array([0.0, 0.0, 0.3]))
    assert np.allclose(attitude_moments(q, [0, 0, 0.3], sp, AttitudeGains(), INERTIA), 0, atol=1e-15)


def test_seed_equation_6_by_hand():
    # roll error 0.01 rad, measured p = 0.2: u2_x = Ixx (3000 * 0.01 + 300 * (0 - 0.2)) = Ixx * -30
    sp = AttitudeSetpoint(quaternion=rotations.from_euler(0.01, 0, 0), body_rates=np.array([1.0, 0, 0]))
    u2 = attitude_moments(rotations.from_euler(0, 0, 0), [0.2, 0, 0], sp, AttitudeGains(), INERTIA)
    assert np.allclose(u2, [INERTIA[0] * -30.0, 0, 0], atol=1e-12)  # p_des = 0 despite the feed-forward
    u2_ff = attitude_moments(rotations.from_euler(0, 0, 0), [0.2, 0, 0], sp, AttitudeGains(), INERTIA,
                             use_feedforward_rates=True)
    assert np.isclose(u2_ff[0], INERTIA[0] * (30.0 + 300 * 0.8))


def test_yaw_error_takes_the_short_way_round():
    sp = AttitudeSetpoint(quaternion=rotations.from_yaw(np.pi - 0.1))
    u2 = attitude_moments(rotations.from_yaw(-np.pi + 0.1), np.zeros(3), sp, AttitudeGains(), INERTIA)
    assert u2[2] < 0


def test_attitude_so3_error_agrees_with_euler_near_hover():
    sp = AttitudeSetpoint(quaternion=rotations.from_euler(0.01, -0.02, 0.5), body_rates=np.zeros(3))
    q = rotations.from_euler(0.0, 0.0, 0.49)
    euler = attitude_moments(q, np.zeros(3), sp, AttitudeGains(), INERTIA)
    so3 = attitude_moments(q, np.zeros(3), sp, AttitudeGains(), INERTIA, attitude_error='so3')
    assert np.allclose(euler, so3, rtol=0.05, atol=1e-3 * np.max(np.abs(euler)))
    assert np.allclose(attitude_moments(sp.quaternion, np.zeros(3), sp, AttitudeGains(), INERTIA,
                                        attitude_error='so3'), 0, atol=1e-15)
    with pytest.raises(ValueError, match='quaternions'):
        attitude_moments(q, np.zeros(3), sp, AttitudeGains(), INERTIA, attitude_error='quaternions')
