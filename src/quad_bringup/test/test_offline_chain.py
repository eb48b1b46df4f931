"""The real-vehicle chain flown offline (quad_bringup.emulated.offline_chain): the odometry stamps' bias
(fly_chain_offline odom_early_s: a clock fallback of the bridge once stamped PX4 SIH's odometry 70-150 ms early). The
bias must be range-checked, reach the stamps position_controller's loop is given and the stamps the scoring uses, and
leave the flight itself alone (under the bridge the loop controls from the newest odometry at the node's time, whatever
its stamp: docs/emulator.md)."""

import math

import numpy as np
import pytest

from quad_bringup.emulated import offline_chain as chain

CONTROL_LOOP = chain.ControlLoop


@pytest.mark.parametrize('bad', [-0.01, chain.ODOM_EARLY_MAX_S + 0.01, math.nan, math.inf])
def test_odom_early_s_range(bad):
    with pytest.raises(ValueError, match='early'):
        chain.odom_early_s_checked(bad)
    with pytest.raises(ValueError, match='early'):   # refused before anything is flown
        chain.fly_chain_offline(None, 0, odom_early_s=bad)


def test_odom_early_s_accepted():
    assert chain.odom_early_s_checked(0) == 0.0
    assert chain.odom_early_s_checked('0.11') == pytest.approx(0.11)
    assert chain.odom_early_s_checked(chain.ODOM_EARLY_MAX_S) == chain.ODOM_EARLY_MAX_S


def _fly_short(monkeypatch, early_s):
    """A 1 m leg after 1 s of hover; (rmse, [(stamp ns, position)] the loop got, (stamps s, positions) scored)."""
    given, scored = [], []

    class SpyLoop(CONTROL_LOOP):
        def set_odometry(self, stamp_ns, state):
            given.append((stamp_ns, state.position.copy()))
            return super().set_odometry(stamp_ns, state)

    real_score = chain.score

    def spy_score(stamps_s, positions, traj, hover_s):
        scored.append((np.array(stamps_s), np.array(positions)))
        return real_score(stamps_s, positions, traj, hover_s)

    monkeypatch.setattr(chain, 'ControlLoop', SpyLoop)
    monkeypatch.setattr(chain, 'score', spy_score)
    rmse = chain.fly_chain_offline(None, 0, odom_early_s=early_s, waypoints=[(0.0, 0.0, 2.0), (1.0, 0.0, 2.0)],
                                   hover_s=1.0)
    assert len(scored) == 1
    return rmse, given, scored[0]


def test_odom_early_s_reaches_the_stamps_not_the_flight(monkeypatch):
    rmse0, given0, (stamps0, pos0) = _fly_short(monkeypatch, 0.0)
    rmse1, given1, (stamps1, pos1) = _fly_short(monkeypatch, 0.11)
    assert len(given0) == len(given1) > 100
    # at 0 the stamp is when the sample was measured: the telemetry latency (20 ms, on the 10 ms grid 20-30 ms)
    # before its arrival at 50 Hz (the first at 20 ms)
    age_ms = [(20 * (i + 1)) - ns / 1e6 for i, (ns, _) in enumerate(given0)]
    assert min(age_ms) > 19.999 and max(age_ms) < 30.001
    # the loop is given each odometry 0.11 s earlier ...
    shift = np.array([a for a, _ in given0]) - np.array([b for b, _ in given1])
    assert np.all(np.abs(shift - 110_000_000) <= 1)
    # ... and the scoring scores it at that stamp
    np.testing.assert_allclose(stamps0 - stamps1, 0.11, atol=1e-9)
    # the flight is the same (position_controller under the bridge does not control from the stamp) ...
    np.testing.assert_array_equal(np.array([p for _, p in given0]), np.array([p for _, p in given1]))
    np.testing.assert_array_equal(pos0, pos1)
    # ... only its score moves
    assert abs(rmse1 - rmse0) > 1e-3
