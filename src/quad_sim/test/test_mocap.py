"""The motion-capture stand-in (quad_sim.mocap): frame rate, stamps of the instant measured, latency, noise
statistics, dropouts, seeding, refusal of bad settings."""

import numpy as np
import pytest

from quad_common import rotations
from quad_sim.mocap import MocapConfig, MotionCapture

STEP_NS = 1_000_000  # 1 kHz of offered truth


def _run(config, seconds=2.0, seed=0, truth=lambda t_s: (np.array([t_s, -2 * t_s, 1.0]), rotations.from_yaw(t_s))):
    """Offer truth every STEP_NS; returns [(delivered at ns, frame)]."""
    mocap = MotionCapture(config, seed=seed)
    out = []
    for k in range(int(seconds * 1e9) // STEP_NS + 1):
        t_ns = k * STEP_NS
        p, q = truth(t_ns * 1e-9)
        out += [(t_ns, f) for f in mocap.offer(t_ns, p, q)]
    return mocap, out


def test_off_by_default_publishes_nothing():
    mocap, out = _run(MocapConfig())
    assert out == [] and mocap.frames_measured == 0


def test_rate_stamps_and_latency():
    _, out = _run(MocapConfig(rate_hz=200.0, latency_s=0.012))
    stamps = np.array([f.stamp_ns for _, f in out])
    assert np.all(np.diff(stamps) == 5_000_000)                      # 200 Hz, on the grid
    assert all(d - f.stamp_ns == 12_000_000 for d, f in out)         # delivered exactly latency later (1 ms steps)
    for _, f in out:                                                 # noise-free: the truth at the stamp
        t = f.stamp_ns * 1e-9
        assert np.allclose(f.position, [t, -2 * t, 1.0]) and np.allclose(f.quaternion, rotations.from_yaw(t))


def test_coarse_offers_stamp_the_instant_measured():
    """Truth offered every 10 ms at 360 Hz: one frame per offer, stamped with that offer's time, not the grid's."""
    mocap = MotionCapture(MocapConfig(rate_hz=360.0))
    frames = []
    for k in range(50):
        frames += mocap.offer(k * 10_000_000, np.full(3, k), rotations.from_yaw(0.0))
    assert [f.stamp_ns for f in frames] == [k * 10_000_000 for k in range(50)]
    assert [f.position[0] for f in frames] == list(range(50))
    assert mocap.offer(49 * 10_000_000, np.zeros(3), rotations.from_yaw(0.0)) == []  # a repeated time: nothing


def test_noise_statistics():
    _, out = _run(MocapConfig(rate_hz=250.0, position_noise_m=0.005, attitude_noise_rad=0.01), seconds=20.0)
    err = np.array([f.position - [f.stamp_ns * 1e-9, -2e-9 * f.stamp_ns, 1.0] for _, f in out])
    assert len(err) == 5001
    assert np.allclose(np.sqrt(np.mean(err ** 2, axis=0)), 0.005, rtol=0.05)   # RMS per axis
    assert np.all(np.abs(np.mean(err, axis=0)) < 0.0005)                       # unbiased
    angles = np.array([2 * np.arccos(min(abs(np.dot(f.quaternion, rotations.from_yaw(f.stamp_ns * 1e-9))), 1.0))
                       for _, f in out])
    # the angle of a rotation vector with N(0, s^2) per axis: RMS s sqrt(3)
    assert np.sqrt(np.mean(angles ** 2)) == pytest.approx(0.01 * np.sqrt(3), rel=0.05)


def test_seeded_noise_repeats_and_differs_by_seed():
    config = MocapConfig(rate_hz=100.0, position_noise_m=0.01, dropout_probability=0.1)
    a = [f.position for _, f in _run(config, seed=3)[1]]
    b = [f.position for _, f in _run(config, seed=3)[1]]
    c = [f.position for _, f in _run(config, seed=4)[1]]
    assert np.array_equal(a, b) and not (len(a) == len(c) and np.array_equal(a, c))


def test_single_frame_dropouts_at_the_probability():
    mocap, out = _run(MocapConfig(rate_hz=100.0, dropout_probability=0.05), seconds=100.0)
    assert mocap.frames_measured == 10001 and mocap.frames_lost + len(out) == 10001
    assert mocap.frames_lost / mocap.frames_measured == pytest.approx(0.05, abs=0.01)


def test_burst_dropouts_lose_every_frame_of_the_burst():
    mocap, out = _run(MocapConfig(rate_hz=100.0, dropout_probability=0.01, dropout_burst_s=0.1), seconds=100.0)
    gaps = np.diff([f.stamp_ns for _, f in out]) / 1e7 - 1       # frames lost between delivered ones
    gaps = gaps[gaps > 0]
    assert len(gaps) > 20 and np.all(gaps >= 11)                  # each burst: its first frame + 0.1 s of frames
    assert mocap.frames_lost == int(gaps.sum())


@pytest.mark.parametrize(('field', 'value'), [('rate_hz', -1.0), ('position_noise_m', float('nan')),
                                              ('dropout_probability', 1.5), ('latency_s', -0.01)])
def test_bad_settings_are_refused_naming_the_field(field, value):
    with pytest.raises(ValueError, match=f'mocap {field} = '):
        MocapConfig(**{field: value})
