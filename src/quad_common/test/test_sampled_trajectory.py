import numpy as np
import pytest

from quad_common.sampled_trajectory import SampledTrajectory


def _quintic_samples(rate_hz):
    """x(t) = t^5 - t^3 is reproduced exactly by quintic Hermite interpolation of its samples."""
    t = np.arange(0, 2 + 1e-9, 1 / rate_hz)
    p, v, a = np.zeros((len(t), 4)), np.zeros((len(t), 4)), np.zeros((len(t), 4))
    p[:, 0], v[:, 0], a[:, 0] = t**5 - t**3, 5 * t**4 - 3 * t**2, 20 * t**3 - 6 * t
    p[:, 3] = 0.5 * t
    v[:, 3] = 0.5
    return t, p, v, a


def test_quintic_reproduced_exactly_between_samples():
    traj = SampledTrajectory(*_quintic_samples(10))
    tq = np.linspace(0.01, 1.99, 77)
    p, v, a, j = traj.evaluate(tq, order=3)
    assert np.allclose(p[:, 0], tq**5 - tq**3, atol=1e-12)
    assert np.allclose(v[:, 0], 5 * tq**4 - 3 * tq**2, atol=1e-10)
    assert np.allclose(a[:, 0], 20 * tq**3 - 6 * tq, atol=1e-9)
    assert np.allclose(j[:, 0], 60 * tq**2 - 6, atol=1e-8)
    assert np.allclose(p[:, 3], 0.5 * tq)


def test_holds_ends_outside_the_time_range():
    traj = SampledTrajectory(*_quintic_samples(10))
    ref = traj.reference(5.0)
    assert np.allclose(ref.position, [0.0, 0, 0] + np.array([2**5 - 2**3, 0, 0]))
    assert np.allclose(ref.velocity, 0) and np.allclose(ref.acceleration, 0)
    assert np.allclose(traj.reference(-1.0).position, 0)


def test_yaw_is_unwrapped_across_pi():
    t = np.array([0.0, 1.0])
    p = np.array([[0, 0, 0, 3.1], [0, 0, 0, -3.1]])
    traj = SampledTrajectory(t, p, np.zeros((2, 4)), np.zeros((2, 4)))
    assert 3.1 < traj.reference(0.5).yaw < 3.2


def test_refuses_non_increasing_times_and_nan():
    t, p, v, a = _quintic_samples(10)
    t[3] = t[2]
    with pytest.raises(ValueError, match='must increase'):
        SampledTrajectory(t, p, v, a)
    t, p, v, a = _quintic_samples(10)
    p[4, 1] = np.nan
    with pytest.raises(ValueError, match='non-finite'):
        SampledTrajectory(t, p, v, a)
