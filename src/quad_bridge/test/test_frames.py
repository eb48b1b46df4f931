"""ENU/FLU <-> NED/FRD against hand-worked vectors."""

import math

import numpy as np
import pytest

from quad_bridge import frames
from quad_common import rotations
from quad_common.types import State


def test_world_vectors_swap_x_y_and_negate_z():
    # 1 m east, 2 m north, 3 m up = 2 m north, 1 m east, 3 m down
    np.testing.assert_allclose(frames.world_enu_ned([1.0, 2.0, 3.0]), [2.0, 1.0, -3.0])
    np.testing.assert_allclose(frames.world_enu_ned(frames.world_enu_ned([1.0, 2.0, 3.0])), [1.0, 2.0, 3.0])


def test_body_vectors_negate_y_and_z():
    # roll right (FLU +x rate), yaw left (FLU +z rate): FRD roll +, yaw -
    np.testing.assert_allclose(frames.body_flu_frd([0.1, 0.2, 0.3]), [0.1, -0.2, -0.3])


@pytest.mark.parametrize('yaw_enu_deg, yaw_ned_deg', [(0.0, 90.0), (90.0, 0.0), (45.0, 45.0), (180.0, -90.0),
                                                      (-90.0, 180.0), (30.0, 60.0)])
def test_yaw_ned_is_90_minus_yaw_enu(yaw_enu_deg, yaw_ned_deg):
    q_ned = frames.quaternion_enu_to_ned(rotations.from_yaw(math.radians(yaw_enu_deg)))
    roll, pitch, yaw = rotations.to_euler(q_ned)
    assert abs(roll) < 1e-12 and abs(pitch) < 1e-12
    assert math.degrees(rotations.wrap_angle(yaw - math.radians(yaw_ned_deg))) == pytest.approx(0.0, abs=1e-9)


def test_identity_attitude_hand_worked():
    # body FLU aligned with ENU: nose east, so in NED the nose points east (yaw 90 deg): q = (0, 0, sin 45, cos 45)
    np.testing.assert_allclose(frames.quaternion_enu_to_ned([0, 0, 0, 1.0]), [0, 0, math.sqrt(0.5), math.sqrt(0.5)],
                               atol=1e-12)


def test_pitch_nose_down_is_the_same_in_both_conventions():
    # FLU: nose down is +pitch about y (left); FRD: nose down is -pitch about y (right)
    q_enu = rotations.from_euler(0.0, 0.3, 0.0)
    roll, pitch, yaw = rotations.to_euler(frames.quaternion_enu_to_ned(q_enu))
    assert (roll, pitch, yaw) == pytest.approx((0.0, -0.3, math.pi / 2), abs=1e-9)


def test_a_body_vector_maps_the_same_either_way():
    rng = np.random.default_rng(3)
    for _ in range(20):
        q = rotations.normalize(rng.standard_normal(4))
        v_flu = rng.standard_normal(3)
        world_enu = rotations.to_matrix(q) @ v_flu
        world_ned = rotations.to_matrix(frames.quaternion_enu_to_ned(q)) @ frames.body_flu_frd(v_flu)
        np.testing.assert_allclose(frames.world_enu_ned(world_enu), world_ned, atol=1e-12)
        back = frames.quaternion_ned_to_enu(frames.quaternion_enu_to_ned(q))
        assert abs(abs(np.dot(back, q)) - 1.0) < 1e-12


def test_state_pair_round_trips():
    s = State(position=np.array([1.0, 2.0, 3.0]), velocity=np.array([0.5, -0.5, 1.0]),
              quaternion=rotations.from_euler(0.1, -0.2, 0.7), body_rates=np.array([0.1, 0.2, 0.3]))
    ned = frames.state_to_ned(s)
    np.testing.assert_allclose(ned.position, [2.0, 1.0, -3.0])
    np.testing.assert_allclose(ned.velocity, [-0.5, 0.5, -1.0])
    np.testing.assert_allclose(ned.body_rates, [0.1, -0.2, -0.3])
    back = frames.state_from_ned(ned)
    for a, b in ((back.position, s.position), (back.velocity, s.velocity), (back.body_rates, s.body_rates)):
        np.testing.assert_allclose(a, b, atol=1e-12)
    assert abs(abs(np.dot(back.quaternion, s.quaternion)) - 1.0) < 1e-12


def test_mavlink_quaternion_order():
    assert frames.to_mavlink_quaternion([0.1, 0.2, 0.3, 0.9]) == [0.9, 0.1, 0.2, 0.3]
    np.testing.assert_allclose(frames.from_mavlink_quaternion([0.9, 0.1, 0.2, 0.3]), [0.1, 0.2, 0.3, 0.9])


def test_the_closed_form_equals_the_product_of_the_two_fixed_rotations():
    rng = np.random.default_rng(5)
    for q in rotations.normalize(rng.standard_normal((50, 4))):
        product = rotations.multiply(frames.Q_NED_ENU, rotations.multiply(q, frames.Q_FLU_FRD))
        assert abs(abs(np.dot(product, frames.quaternion_enu_to_ned(q))) - 1.0) < 1e-12
        assert frames.quaternion_enu_to_ned(q)[3] >= 0.0


def test_the_setpoint_paths_quaternion_is_the_composition_exactly():
    """enu_to_mavlink_quaternion is the send path's shortcut of to_mavlink_quaternion(quaternion_enu_to_ned(q)):
    bit for bit the same, w >= 0 flips included."""
    rng = np.random.default_rng(3)
    qs = [*rng.normal(size=(500, 4)), np.array([0.0, 0.0, -0.5, 0.5]), np.array([0.0, 0.0, 0.0, 1.0]), [1, 0, 0, 0]]
    for q in qs:
        assert frames.enu_to_mavlink_quaternion(q) == frames.to_mavlink_quaternion(frames.quaternion_enu_to_ned(q))
