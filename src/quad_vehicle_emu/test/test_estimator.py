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


def test_bad_values_are_refused_naming_the_flag():
    with pytest.raises(ValueError, match='--estimator-lag-s = -1'):
        Estimate(lag_s=-1.0)
    with pytest.raises(ValueError, match='--estimator-wander-tau-s'):
        Estimate(tau_s=0.0)
