"""The autopilot's estimate (quad_vehicle_emu.estimator): the truth by default; lagged and wandering as asked."""

import numpy as np
import pytest

from quad_common.types import State
from quad_vehicle_emu.estimator import Estimate


def _truth(t_s):
    return State(position=np.array([t_s, 0.0, 2.0]), velocity=np.array([1.0, 0.0, 0.0]))


def test_by_default_the_estimate_is_the_truth():
    estimate = Estimate()
    truth = _truth(3.0)
    assert estimate.step(3.0, truth) is truth


def test_the_estimate_trails_by_its_lag_and_wanders_by_its_rms():
    """0.15 s behind a vehicle flying at 1 m/s: 0.15 m short (to one 10 ms tick); over 20 correlation times the
    wander's RMS is sigma within 25 % per axis, and it moves slowly (about 0.5 m a minute at 0.5 m, 60 s)."""
    lagged = Estimate(lag_s=0.15)
    for k in range(100):
        est = lagged.step(0.01 * k, _truth(0.01 * k))
    assert est.position[0] == pytest.approx(0.99 - 0.15, abs=0.011) and est.velocity[0] == 1.0
    wandering = Estimate(wander_m=0.5, wander_z_m=0.8, tau_s=60.0, seed=3)
    errors = np.array([wandering.step(0.1 * k, _truth(0.0)).position - [0.0, 0.0, 2.0] for k in range(12000)])
    rms = np.sqrt(np.mean(errors ** 2, axis=0))
    assert rms == pytest.approx([0.5, 0.5, 0.8], rel=0.25)
    per_minute = np.abs(errors[600::600, 0] - errors[:-600:600, 0])
    assert 0.1 < np.median(per_minute) < 0.8


def test_only_the_position_trails_velocity_and_attitude_are_now():
    """Accelerating at 2 m/s^2 behind a 0.15 s lag: the position is the truth's of 0.15 s ago, the velocity the
    truth's now (EKF2's output predictor; a lagged velocity made control_se3 diverge where PX4 SIH flew it)."""
    lagged = Estimate(lag_s=0.15)
    for k in range(101):
        t = 0.01 * k
        truth = State(position=np.array([t * t, 0.0, 2.0]), velocity=np.array([2.0 * t, 0.0, 0.0]),
                      quaternion=np.array([0.0, 0.0, np.sin(t / 2), np.cos(t / 2)]))
        est = lagged.step(t, truth)
    assert est.position[0] == pytest.approx((1.0 - 0.15) ** 2, abs=0.025)
    assert est.velocity[0] == 2.0 and np.array_equal(est.quaternion, truth.quaternion)


def test_the_wander_is_smooth_as_ekf2_output_predictor_publishes_it():
    """Stepped at the emulator's 100 Hz and read at 50 Hz (odometry), the wander's second difference (what a
    position loop sees as jitter) stays under 3 mm RMS: EKF2 spreads its corrections over EKF2_TAU_POS 0.25 s.
    The Gauss-Markov process alone (white increments) gives ~2 cm at 0.6 m / 60 s, and its RMS is kept."""
    wandering = Estimate(wander_m=0.6, wander_z_m=0.8, tau_s=60.0, seed=5)
    errors = np.array([wandering.step(0.01 * k, _truth(0.0)).position - [0.0, 0.0, 2.0] for k in range(120000)])
    at_50_hz = errors[::2]
    jitter = np.sqrt(np.mean((at_50_hz[2:] - 2 * at_50_hz[1:-1] + at_50_hz[:-2]) ** 2, axis=0))
    assert np.all(jitter < 0.003), jitter
    assert np.sqrt(np.mean(errors ** 2, axis=0)) == pytest.approx([0.6, 0.6, 0.8], rel=0.35)


def test_bad_values_are_refused_naming_the_flag():
    with pytest.raises(ValueError, match='--estimator-lag-s = -1'):
        Estimate(lag_s=-1.0)
    with pytest.raises(ValueError, match='--estimator-wander-tau-s'):
        Estimate(tau_s=0.0)


def test_velocity_noise_from_sih_accelerometer_over_ekf2_tau_vel():
    """`velocity_noise_mps`: per body axis a Gauss-Markov process of EKF2_TAU_VEL (0.25 s) with the RMS asked
    (PX4 SIH's: 0.0125, 0.0425, 0.035 m/s from its accelerometer noise at 200 Hz), rotated by the attitude now;
    the position and the seed's wander are untouched."""
    from quad_vehicle_emu.estimator import SIH_VELOCITY_NOISE_MPS
    assert SIH_VELOCITY_NOISE_MPS == pytest.approx((0.0125, 0.0425, 0.035), abs=1e-4)
    yawed = np.array([0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4)])   # 90 deg: body x is world y
    truth = State(position=np.array([1.0, 2.0, 3.0]), velocity=np.zeros(3), quaternion=yawed)
    noisy = Estimate(wander_m=0.5, seed=4, velocity_noise_mps=(0.01, 0.05, 0.03))
    plain = Estimate(wander_m=0.5, seed=4)
    samples, positions = [], []
    for k in range(60000):
        est = noisy.step(0.01 * k, truth)
        samples.append(est.velocity)
        positions.append(est.position - plain.step(0.01 * k, truth).position)
    v = np.array(samples)
    assert np.sqrt(np.mean(v ** 2, axis=0)) == pytest.approx([0.05, 0.01, 0.03], rel=0.15)
    corr = np.mean(v[25:, 1] * v[:-25, 1]) / np.mean(v[:, 1] ** 2)      # 0.25 s apart: about 1 / e
    assert 0.25 < corr < 0.5
    assert np.all(np.array(positions) == 0.0)
    with pytest.raises(ValueError, match='--estimator-velocity-noise-mps'):
        Estimate(velocity_noise_mps=(0.1, -0.1, 0.0))


def test_velocity_wander_is_slow_at_its_rms_and_leaves_the_position_alone():
    """`velocity_wander_mps` / `_z_mps` / `_tau_s` (PX4 SIH: 0.1-0.32 / 0.14-0.19 m/s, 2-5 s): per world axis a
    Gauss-Markov process of that RMS and correlation time added to the velocity; the position and the other
    streams (wander, velocity noise) unchanged for a seed."""
    truth = State(position=np.array([1.0, 2.0, 3.0]), velocity=np.array([0.5, 0.0, 0.0]))
    wandering = Estimate(wander_m=0.5, seed=4, velocity_wander_mps=0.2, velocity_wander_z_mps=0.15,
                         velocity_wander_tau_s=3.0)
    plain = Estimate(wander_m=0.5, seed=4)
    errors, positions = [], []
    for k in range(60000):
        est = wandering.step(0.05 * k, truth)
        errors.append(est.velocity - truth.velocity)
        positions.append(est.position - plain.step(0.05 * k, truth).position)
    v = np.array(errors)
    assert np.sqrt(np.mean(v ** 2, axis=0)) == pytest.approx([0.2, 0.2, 0.15], rel=0.15)
    corr = np.mean(v[60:, 0] * v[:-60, 0]) / np.mean(v[:, 0] ** 2)      # 3 s apart: about 1 / e
    assert 0.25 < corr < 0.5
    assert np.all(np.array(positions) == 0.0)
    with pytest.raises(ValueError, match='--estimator-velocity-wander-mps'):
        Estimate(velocity_wander_mps=-0.1)
    with pytest.raises(ValueError, match='--estimator-velocity-wander-tau-s'):
        Estimate(velocity_wander_mps=0.1, velocity_wander_tau_s=0.0)
