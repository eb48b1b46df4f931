"""The velocity blend (quad_control.velocity_blend): a slow velocity error is replaced by the position's
derivative, fast motion is kept, and on PX4 SIH's own odometry it removes most of EKF2's velocity error."""

import gzip
from pathlib import Path

import numpy as np
import pytest

from quad_common.paths import resolve_config
from quad_common.types import State
from quad_common.vehicle import load_vehicle
from quad_control.loop import ControlLoop
from quad_control.parameters import gains_from
from quad_control.position import PositionController
from quad_control.velocity_blend import VelocityBlend

PERIOD_NS = 20_000_000   # odometry at 50 Hz
# PX4 v1.16.0 SITL + SIH flight (control_real through the bridge, the 3 m square): 30 s of the odometry the bridge
# delivered (its stamps, EKF2's position and velocity, x / y as PX4 logged them) and SIH's true velocity then
PX4_SIH_ODOMETRY = Path(__file__).parent / 'data' / 'px4_sih_odometry.csv.gz'


def _state(position, velocity):
    return State(position=np.array(position, float), velocity=np.array(velocity, float))


def _fly(tau_s, n, position_at, velocity_at):
    blend = VelocityBlend()
    return [blend(k * PERIOD_NS, _state(position_at(k * 0.02), velocity_at(k * 0.02)), tau_s) for k in range(n)]


def test_a_constant_velocity_error_is_replaced_by_the_position_derivative():
    truth_mps = np.array([0.8, -0.3, 0.1])
    bias_mps = np.array([0.2, 0.15, -0.1])
    flown = _fly(0.2, 100, lambda t: truth_mps * t, lambda t: truth_mps + bias_mps)
    assert np.abs(flown[-1].velocity - truth_mps).max() < 1e-3
    removed = (truth_mps + bias_mps - flown[10].velocity) / bias_mps   # tau = 0.2 s = 10 samples later: 1 - 1/e
    assert removed == pytest.approx(np.full(3, 1 - np.exp(-1)), abs=0.03)
    unblended = _fly(0.0, 100, lambda t: truth_mps * t, lambda t: truth_mps + bias_mps)
    assert np.allclose(unblended[-1].velocity, truth_mps + bias_mps)


def test_fast_motion_is_the_odometry_velocity_at_once():
    """A 2 Hz oscillation the position and the velocity agree on: the blend adds (almost) nothing, with no lag."""
    w = 2 * np.pi * 2.0
    flown = _fly(0.2, 200, lambda t: [0.1 * np.sin(w * t), 0, 0], lambda t: [0.1 * w * np.cos(w * t), 0, 0])
    got = np.array([s.velocity[0] for s in flown[50:]])
    want = np.array([0.1 * w * np.cos(w * k * 0.02) for k in range(50, 200)])
    assert np.abs(got - want).max() < 0.05 * 0.1 * w   # the finite difference's own error, not a lag


def test_an_estimate_consistent_with_its_position_is_flown_unchanged_while_accelerating():
    """p = a t^2 / 2, v = a t: the difference quotient equals the mean velocity over its interval, so no correction
    (a backward difference against the newest velocity would lag it by a dt / 2)."""
    accel = np.array([2.0, -1.0, 0.5])
    flown = _fly(0.2, 100, lambda t: 0.5 * accel * t * t, lambda t: accel * t)
    assert np.abs(flown[-1].velocity - accel * 99 * 0.02).max() < 1e-9


def test_a_repeated_stamp_leaves_the_correction_and_zero_clears_it():
    blend = VelocityBlend()
    blend(0, _state([0, 0, 0], [0, 0, 0]), 0.2)
    first = blend(PERIOD_NS, _state([0.02, 0, 0], [0, 0, 0]), 0.2).velocity.copy()
    again = blend(PERIOD_NS, _state([0.02, 0, 0], [0, 0, 0]), 0.2).velocity
    assert first[0] > 0 and np.array_equal(first, again)
    off = _state([0.04, 0, 0], [0, 0, 0])
    assert blend(2 * PERIOD_NS, off, 0.0) is off and not blend.correction_mps.any()


def test_the_loop_flies_the_blend_its_gains_name_at_the_time():
    vehicle = load_vehicle(resolve_config('config/vehicles/crazyflie.yaml'))
    controller = PositionController('pd', gains_from({'velocity_from_position_s': 0.2}), vehicle)
    loop = ControlLoop(controller, 100.0)
    for k in range(100):   # still, but the odometry says 0.3 m/s
        loop.set_odometry(k * PERIOD_NS, _state([0, 0, 1], [0.3, 0, 0]))
    assert abs(loop.odom[1].velocity[0]) < 1e-3
    controller.gains = gains_from({})   # a parameter change: the odometry's velocity again
    loop.set_odometry(100 * PERIOD_NS, _state([0, 0, 1], [0.3, 0, 0]))
    assert loop.odom[1].velocity[0] == 0.3


def test_on_px4_sih_odometry_the_blend_halves_ekf2_velocity_error():
    with gzip.open(PX4_SIH_ODOMETRY, 'rt') as f:
        data = np.loadtxt(f, delimiter=',', skiprows=1)
    stamp_s, position, velocity, truth = data[:, 0], data[:, 1:3], data[:, 3:5], data[:, 5:7]
    assert np.ptp(stamp_s) > 25 and np.sqrt(np.mean(np.sum(truth ** 2, axis=1))) > 0.4   # a flight, not a hover

    def rms_error(tau_s):
        blend = VelocityBlend()
        flown = np.array([blend(round(t * 1e9), _state([*p, 0], [*v, 0]), tau_s).velocity[:2]
                          for t, p, v in zip(stamp_s, position, velocity)])
        return np.sqrt(np.mean((flown - truth) ** 2, axis=0))

    ekf2, blended = rms_error(0.0), rms_error(0.2)
    print(f'velocity error RMS x / y: EKF2 {ekf2.round(3).tolist()} m/s, blended at 0.2 s {blended.round(3).tolist()}')
    assert ekf2[0] > 0.15                          # the error this is for
    assert np.all(blended < 0.6 * ekf2)
