"""quad_control.pose_state: the state from motion-capture poses (alpha-beta velocity)."""

import math

import numpy as np
import pytest

from quad_control.pose_state import PoseStateFilter, alpha_beta_gains

LEVEL = [0.0, 0.0, 0.0, 1.0]


def fly(filt, positions, dt_s=0.01, quaternions=None, t0_s=1.0):
    states = []
    for k, p in enumerate(positions):
        q = LEVEL if quaternions is None else quaternions[k]
        states.append(filt.update(round((t0_s + k * dt_s) * 1e9), p, q))
    return states


def test_gains_are_the_steady_state_kalman_gains_of_the_tracking_index():
    # lambda = 1: s = (5 - 3) / 4 = 0.5, alpha = 0.75, beta = 2 (1.25) - 4 (0.5) = 0.5
    assert alpha_beta_gains(0.01, 0.001, 10.0) == pytest.approx((0.75, 0.5))
    a_slow, _ = alpha_beta_gains(0.01, 0.001, 1.0)
    a_fast, _ = alpha_beta_gains(0.01, 0.001, 100.0)
    assert 0 < a_slow < 0.75 < a_fast < 1   # more acceleration trusts the pose more


def test_a_constant_velocity_is_followed_without_lag_and_uneven_frames_are_taken():
    filt = PoseStateFilter(0.001, 2.0, 0.2)
    t = np.cumsum(np.r_[0.0, np.tile([0.005, 0.012, 0.008], 100)])     # an uneven stream
    states = [filt.update(round((1.0 + ti) * 1e9), [0.8 * ti, -0.3 * ti, 1.0 + 0.1 * ti], LEVEL) for ti in t]
    assert np.allclose(states[-1].velocity, [0.8, -0.3, 0.1], atol=1e-6)
    assert np.allclose(states[-1].position, [0.8 * t[-1], -0.3 * t[-1], 1.0 + 0.1 * t[-1]], atol=1e-9)


def test_the_velocity_is_several_times_quieter_than_differences_of_the_poses():
    rng = np.random.default_rng(0)
    truth = np.array([[0.8 * 0.01 * k, 0.0, 1.0] for k in range(2000)])
    noisy = truth + rng.normal(0.0, 0.001, truth.shape)
    states = fly(PoseStateFilter(0.001, 2.0, 0.2), noisy)
    filtered = np.array([s.velocity for s in states[200:]]) - [0.8, 0.0, 0.0]
    differences = np.diff(noisy, axis=0)[199:] / 0.01 - [0.8, 0.0, 0.0]
    rms = lambda e: math.sqrt(float(np.mean(np.square(e))))   # noqa: E731
    assert rms(filtered) * 5 < rms(differences)


def test_a_gap_longer_than_max_gap_restarts_at_the_pose_with_zero_velocity():
    filt = PoseStateFilter(0.001, 2.0, 0.1)
    fly(filt, [[0.01 * k, 0.0, 1.0] for k in range(50)])     # 1 m/s
    state = filt.update(round(3.0 * 1e9), [5.0, 0.0, 1.0], LEVEL)
    assert filt.restarts == 1
    assert np.allclose(state.position, [5.0, 0.0, 1.0]) and np.allclose(state.velocity, 0.0)


def test_body_rates_from_consecutive_attitudes():
    yaw_rate = 0.5
    quats = [[0.0, 0.0, math.sin(0.5 * yaw_rate * 0.01 * k), math.cos(0.5 * yaw_rate * 0.01 * k)] for k in range(200)]
    states = fly(PoseStateFilter(0.001, 2.0, 0.2), [[0.0, 0.0, 1.0]] * 200, quaternions=quats)
    assert np.allclose(states[-1].body_rates, [0.0, 0.0, yaw_rate], atol=1e-3)


@pytest.mark.parametrize('stamp_s, position, match', [
    (1.0, [0.0, 0.0, 1.0], 'not after the last'),
    (2.0, [0.0, math.nan, 1.0], 'not three finite numbers'),
])
def test_an_old_or_non_finite_pose_is_refused_and_changes_nothing(stamp_s, position, match):
    filt = PoseStateFilter(0.001, 2.0, 0.2)
    filt.update(round(1.0 * 1e9), [0.0, 0.0, 1.0], LEVEL)
    with pytest.raises(ValueError, match=match):
        filt.update(round(stamp_s * 1e9), position, LEVEL)
    assert filt.stamp_ns == round(1.0 * 1e9)


@pytest.mark.parametrize('field', ['position_noise_m', 'acceleration_mps2', 'max_gap_s'])
def test_a_non_positive_setting_is_refused(field):
    values = {'position_noise_m': 0.001, 'acceleration_mps2': 2.0, 'max_gap_s': 0.2, field: 0.0}
    with pytest.raises(ValueError, match='must be a finite number > 0'):
        PoseStateFilter(**values)
