"""quad_control.drag_estimate on a scripted horizontal vehicle, v' = u - D v + b, flown by a PD on its measured
(noisy) velocity, so the noise reaches the command as it does in flight; and through PositionController."""

from dataclasses import replace

import numpy as np
import pytest

from quad_common import rotations
from quad_common.paths import resolve_config
from quad_common.types import GRAVITY_MPS2, Reference, State
from quad_common.vehicle import load_vehicle
from quad_control.drag_estimate import MAX_PER_S, DragEstimate
from quad_control.position import PositionController, PositionGains, desired_acceleration

DT_S = 0.01
VEHICLE = load_vehicle(resolve_config('config/vehicles/px4_quad.yaml'))


def circle(t_s, speed_mps=0.8, period_s=8.0):
    """A circle's (velocity, acceleration) at t_s."""
    w = 2 * np.pi / period_s
    return (speed_mps * np.array([np.cos(w * t_s), np.sin(w * t_s)]),
            speed_mps * w * np.array([-np.sin(w * t_s), np.cos(w * t_s)]))


def forward(t_s):
    """Always flying +x, 0.5-1.1 m/s, weaving in y: the plan's velocity has a mean, so a bias would pass for drag."""
    w = 2 * np.pi / 6.0
    return (np.array([0.8 + 0.3 * np.sin(w * t_s), 0.4 * np.cos(w * t_s)]),
            np.array([0.3 * w * np.cos(w * t_s), -0.4 * w * np.sin(w * t_s)]))


def hover(t_s):
    return np.zeros(2), np.zeros(2)


def fly(estimate, drag_per_s, duration_s, plan=circle, bias_mps2=(0.0, 0.0), noise_mps=0.2, wander_mps=0.1,
        seed=0, t0_s=0.0, push=None):
    """Flies the scripted vehicle for duration_s, feeding `estimate` every step; returns the D it ends with.
    The measured velocity: the truth + white noise (noise_mps per sample) + a Gauss-Markov wander (3 s);
    push(t): an extra external acceleration (a gust)."""
    rng = np.random.default_rng(seed)
    v = plan(t0_s)[0].copy()
    wander = np.zeros(2)
    a_wander = np.exp(-DT_S / 3.0)
    force = np.zeros(2)
    for k in range(int(round(duration_s / DT_S))):
        t = t0_s + k * DT_S
        v_t, a_t = plan(t)
        external = -drag_per_s * v + np.asarray(bias_mps2) + (push(t) if push else 0.0)
        v = v + (force + external) * DT_S          # the force commanded at the previous step acts over this one
        wander = a_wander * wander + wander_mps * np.sqrt(1 - a_wander ** 2) * rng.standard_normal(2)
        measured = v + wander + noise_mps * rng.standard_normal(2)
        estimate.update(np.append(measured, 0.0), np.append(force, GRAVITY_MPS2), np.append(v_t, 0.0), DT_S)
        force = a_t + estimate.drag_per_s * v_t + 2.0 * (v_t - measured)   # the feed-forward flies what it learnt
    return estimate.drag_per_s


@pytest.mark.parametrize(('drag_per_s', 'seed'), [(1.0, 0), (1.0, 1), (1.0, 2), (0.5, 1), (2.0, 0)])
def test_learns_a_known_drag_through_noisy_velocity(drag_per_s, seed):
    """From 0, 40 s of a circle at 0.8 m/s, the velocity 0.2 m/s noisy per sample and wandering 0.1 m/s (the
    wander biases D toward 0 by ~3 %: var(wander) / var(phi))."""
    learnt = fly(DragEstimate(0.0, 20.0), drag_per_s, 40.0, seed=seed)
    assert learnt == pytest.approx(drag_per_s, rel=0.12)


def test_learns_within_seconds_of_moving():
    """Half a circle (4 s) brings D from 0 to within 15 %: the first leg of a flight already carries it."""
    assert fly(DragEstimate(0.0, 20.0), 1.0, 4.0) == pytest.approx(1.0, rel=0.15)


@pytest.mark.parametrize('seed', [0, 1])
def test_no_drag_stays_near_zero(seed):
    estimate = DragEstimate(0.0, 20.0)
    assert fly(estimate, 0.0, 40.0, seed=seed) < 0.05


def test_a_wrong_prior_is_unlearnt():
    """Started from 1.5 on a vehicle without drag (a profile identified on another vehicle)."""
    assert fly(DragEstimate(1.5, 20.0), 0.0, 40.0) < 0.05


@pytest.mark.parametrize('bias', [(0.5, -0.3), (-0.4, 0.2)])
@pytest.mark.parametrize('drag_per_s', [0.0, 1.0])
def test_a_constant_external_acceleration_is_not_taken_for_drag(drag_per_s, bias):
    """Flying always forward (the velocity's mean is not 0) in a steady push (wind, a tilt bias): the per-axis
    bias takes it (a fit without one would be off by -b_x / 0.8 = 0.4-0.6 1/s; the weaving's smaller velocity
    variance leaves the wander's bias toward 0 at ~6 %)."""
    learnt = fly(DragEstimate(0.0, 20.0), drag_per_s, 40.0, plan=forward, bias_mps2=bias, wander_mps=0.05)
    assert learnt == pytest.approx(drag_per_s, abs=0.1)


def test_hover_neither_learns_nor_forgets():
    """After learning D = 1, two minutes of hover with noisy, wandering velocity and gusts pushing the vehicle
    about (the plan at rest): D stays where it was (a fit on the hover's velocity would go to ~0)."""
    estimate = DragEstimate(0.0, 20.0)
    assert fly(estimate, 1.0, 30.0) == pytest.approx(1.0, rel=0.12)
    learnt = fly(estimate, 1.0, 3.0, plan=hover, t0_s=30.0)   # the plan has stopped (its filtered speed decays)

    def gusts(t):
        return 0.8 * np.array([np.sin(1.3 * t), np.cos(0.7 * t)])

    held = fly(estimate, 1.0, 120.0, plan=hover, push=gusts, t0_s=33.0, noise_mps=0.3, wander_mps=0.3, seed=5)
    assert held == pytest.approx(learnt, abs=0.002)


def test_stays_within_its_range_and_finite():
    """A vehicle pushed along its velocity (negative drag) clamps at 0, a huge drag at MAX_PER_S; non-finite
    or absurd samples and dt 0 change nothing."""
    assert fly(DragEstimate(1.0, 5.0), -1.0, 20.0) == 0.0
    assert fly(DragEstimate(1.0, 5.0), 8.0, 20.0) == MAX_PER_S
    estimate = DragEstimate(0.7, 5.0)
    fly(estimate, 1.0, 10.0)
    before = estimate.drag_per_s
    for bad in ([np.nan, 0, 0], [np.inf, 0, 0]):
        estimate.update(bad, [0, 0, GRAVITY_MPS2], [0.8, 0, 0], DT_S)
        estimate.update([0.8, 0, 0], bad, [0.8, 0, 0], DT_S)
        estimate.update([0.8, 0, 0], [0, 0, GRAVITY_MPS2], bad, DT_S)
    estimate.update([0.8, 0, 0], [0, 0, GRAVITY_MPS2], [0.8, 0, 0], 0.0)
    assert estimate.drag_per_s == before and np.isfinite(estimate.drag_per_s)
    for _ in range(3):   # finite but no flight (an estimate's glitch): left out, the fit goes on
        estimate.update([1e200, 0, 0], [0, 0, GRAVITY_MPS2], [0.8, 0, 0], DT_S)
    assert estimate.drag_per_s == before
    assert fly(estimate, 2.0, 20.0, t0_s=10.0) == pytest.approx(2.0, rel=0.12)
    with pytest.raises(ValueError, match='learning_time_s'):
        DragEstimate(0.0, 0.0)


# --- through PositionController -----------------------------------------------------------------------------------

def _state(velocity=(0.0, 0.0, 0.0)):
    return State(position=np.zeros(3), velocity=np.array(velocity, dtype=float),
                 quaternion=np.array([0.0, 0.0, 0.0, 1.0]), body_rates=np.zeros(3))


def _ref(velocity=(0.0, 0.0, 0.0)):
    return Reference(position=np.zeros(3), velocity=np.array(velocity, dtype=float))


def test_controller_flies_the_learnt_drag_horizontally_and_keeps_it_across_resets():
    """While learning, eq. 1's drag feed-forward is the learnt D on x and y (drag_feedforward_per_s on z); a reset
    (a new plan, an engagement) keeps it; learning switched off flies drag_feedforward_per_s again."""
    gains = replace(PositionGains(), drag_feedforward_per_s=0.3, drag_learning_time_s=20.0)
    ctl = PositionController('pid', gains, VEHICLE)
    ctl.update(_state(), _ref(), DT_S)
    assert ctl.drag is not None and ctl.drag.drag_per_s == pytest.approx(0.3)   # starts from the profile's D
    ctl.drag.drag_per_s = 1.2                                                    # as if learnt
    v_t = (0.8, -0.5, 0.2)
    ctl.reset()
    sp, _ = ctl.update(_state(v_t), _ref(v_t), DT_S)
    assert ctl.drag.drag_per_s == pytest.approx(1.2)
    assert ctl.drag_per_s == pytest.approx([1.2, 1.2, 0.3])
    expected = desired_acceleration(_state(v_t), _ref(v_t), gains, ctl.integral_m_s, np.array([1.2, 1.2, 0.3]))
    fixed = PositionController('pid', replace(gains, drag_feedforward_per_s=0.0, drag_learning_time_s=0.0), VEHICLE)
    asked = fixed.update(_state(v_t), Reference(position=np.zeros(3), velocity=np.array(v_t),
                                                acceleration=expected), DT_S)[0]
    assert np.allclose(sp.quaternion, asked.quaternion, atol=1e-12)
    assert sp.specific_force_mps2 == pytest.approx(asked.specific_force_mps2, abs=1e-12)
    ctl.gains = replace(gains, drag_learning_time_s=0.0)
    ctl.update(_state(v_t), _ref(v_t), DT_S)
    assert ctl.drag is None and ctl.drag_per_s == pytest.approx([0.3, 0.3, 0.3])


def test_controller_learns_the_drag_of_a_vehicle_it_flies():
    """PositionController (pid, control_real's gains) on the scripted vehicle in 3D, level attitude commands
    turned into force by the setpoint it returns: D = 1 learnt from 0 within 8 % in 40 s of a circle."""
    gains = replace(PositionGains(), kp=np.array([2.0, 2.0, 6.0]), kd=np.array([2.5, 2.5, 4.0]),
                    ki=np.array([1.0, 1.0, 3.0]), drag_learning_time_s=20.0)
    ctl = PositionController('pid', gains, VEHICLE)
    rng = np.random.default_rng(0)
    p, v = np.zeros(3), np.array([0.8, 0.0, 0.0])
    q = np.array([0.0, 0.0, 0.0, 1.0])
    for k in range(4000):
        t = k * DT_S
        v_t, a_t = circle(t)
        w = 2 * np.pi / 8.0
        p_t = 0.8 / w * np.array([np.sin(w * t), 1 - np.cos(w * t), 0.0])
        ref = Reference(position=p_t, velocity=np.append(v_t, 0.0), acceleration=np.append(a_t, 0.0))
        measured = State(position=p, velocity=v + 0.1 * rng.standard_normal(3), quaternion=q, body_rates=np.zeros(3))
        sp, _ = ctl.update(measured, ref, DT_S if k else 0.0)
        q = sp.quaternion                                      # the attitude reached at once
        force = sp.specific_force_mps2 * rotations.to_matrix(q)[:, 2] - GRAVITY_MPS2 * np.array([0.0, 0.0, 1.0])
        v = v + (force - 1.0 * np.array([v[0], v[1], 0.0])) * DT_S
        p = p + v * DT_S
    assert ctl.drag.drag_per_s == pytest.approx(1.0, rel=0.08)
