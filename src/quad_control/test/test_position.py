"""Position controllers against hand-computed cases, invariants and closed-loop linear analysis."""

import math
from dataclasses import replace

import numpy as np
import pytest

from quad_common import rotations
from quad_common.paths import resolve_config
from quad_common.types import GRAVITY_MPS2, Reference, State
from quad_common.vehicle import load_vehicle
from quad_control.position import Limits, PositionController, PositionGains

G = GRAVITY_MPS2
VEHICLE = load_vehicle(resolve_config('config/vehicles/crazyflie.yaml'))
M = VEHICLE.mass_kg
SEED = PositionGains()


def _state(position=(0, 0, 1), velocity=(0, 0, 0), quaternion=(0, 0, 0, 1)):
    return State(position=np.array(position, float), velocity=np.array(velocity, float),
                 quaternion=np.array(quaternion, float))


def _ref(position=(0, 0, 1), velocity=(0, 0, 0), acceleration=(0, 0, 0), jerk=(0, 0, 0), yaw=0.0, yaw_rate=0.0):
    return Reference(position=np.array(position, float), velocity=np.array(velocity, float),
                     acceleration=np.array(acceleration, float), jerk=np.array(jerk, float), yaw=yaw,
                     yaw_rate=yaw_rate)


def _euler(sp):
    return rotations.to_euler(sp.quaternion)


def _tilt_rad(q):
    return math.acos(np.clip(rotations.to_matrix(q)[2, 2], -1, 1))


def _law(controller):
    """law(state, ref, gains, vehicle, limits=None, integral=None): one PositionController.update, the production
    entry, of a fresh controller; `integral` presets pid's error integral (dt = 0 leaves it as it is)."""
    def law(state, ref, gains, vehicle, limits=None, integral=None):
        ctl = PositionController(controller, gains, vehicle, limits)
        if integral is not None:
            ctl.integral_m_s = np.array(integral, dtype=float)
        return ctl.update(state, ref, 0.0)
    return law


pd, pid, se3 = _law('pd'), _law('pid'), _law('se3')


# --- hover and the seed's small-angle formulas ------------------------------------------------

@pytest.mark.parametrize('law', [pd, se3, pid])
def test_hover_equilibrium(law):
    yaw = 0.7
    sp, sat = law(_state(quaternion=rotations.from_yaw(yaw)), _ref(yaw=yaw), SEED, VEHICLE)
    assert np.allclose(_euler(sp), [0, 0, yaw], atol=1e-12)
    assert math.isclose(sp.specific_force_mps2 * M, M * G, rel_tol=1e-12)
    assert np.allclose(sp.body_rates, 0, atol=1e-15) and not sat.any


def test_seed_equations_by_hand():
    # x error 0.1 m, y velocity error 0.2 m/s, z error -0.05 m and vz 0.1 m/s, yaw 0:
    # eq. 1: a_des = (5 * 0.1, 5 * 0.2, 20 * -0.05 + 10 * -0.1) = (0.5, 1.0, -2.0)
    sp, _ = pd(_state(position=(-0.1, 0, 1.05), velocity=(0, -0.2, 0.1)), _ref(), SEED, VEHICLE)
    roll, pitch, yaw = _euler(sp)
    assert math.isclose(pitch, 0.5 / G, rel_tol=1e-12)          # eq. 4 with psi = 0
    assert math.isclose(roll, -1.0 / G, rel_tol=1e-12)          # eq. 3 with psi = 0
    assert yaw == 0.0                                           # eq. 5
    assert math.isclose(sp.specific_force_mps2 * M, M * G + M * -2.0, rel_tol=1e-12)  # eq. 2


def test_seed_equations_with_yaw_and_feedforward():
    # psi_T = 90 deg: eq. 3 phi = a1 / g, eq. 4 theta = a2 / g; feed-forward a_T adds straight to eq. 1
    sp, _ = pd(_state(), _ref(acceleration=(0.3, -0.2, 0.5), yaw=math.pi / 2, yaw_rate=0.4), SEED, VEHICLE)
    roll, pitch, yaw = _euler(sp)
    assert math.isclose(roll, 0.3 / G, rel_tol=1e-9) and math.isclose(pitch, -0.2 / G, rel_tol=1e-9)
    assert math.isclose(yaw, math.pi / 2, rel_tol=1e-12)
    assert math.isclose(sp.specific_force_mps2, G + 0.5, rel_tol=1e-12)
    assert sp.body_rates.tolist() == [0.0, 0.0, 0.4]          # the seed's r_des = yaw rate
    no_ff, _ = pd(_state(), _ref(acceleration=(0.3, -0.2, 0.5)), replace(SEED, use_feedforward=False), VEHICLE)
    assert np.allclose(_euler(no_ff), 0) and no_ff.specific_force_mps2 == G


def test_x_and_y_gains_are_separate():
    gains = replace(SEED, kp=np.array([5.0, 8.0, 20.0]), kd=np.array([5.0, 3.0, 10.0]))
    sp, _ = pd(_state(position=(-0.1, -0.1, 1), velocity=(0.1, 0.1, 0)), _ref(), gains, VEHICLE)
    roll, pitch, _ = _euler(sp)
    assert math.isclose(pitch, (5 * 0.1 - 5 * 0.1) / G + 0.0, abs_tol=1e-12)
    assert math.isclose(roll, -(8 * 0.1 - 3 * 0.1) / G, rel_tol=1e-12)


def test_controllers_agree_near_hover():
    rng = np.random.default_rng(1)
    for _ in range(50):
        state = _state(position=rng.normal(0, 0.01, 3) + [0, 0, 1], velocity=rng.normal(0, 0.01, 3))
        ref = _ref(acceleration=rng.normal(0, 0.01, 3), yaw=rng.uniform(-3, 3))
        state.quaternion = rotations.from_yaw(ref.yaw)
        a, _ = pd(state, ref, SEED, VEHICLE)
        b, _ = pid(state, ref, SEED, VEHICLE)
        c, _ = se3(state, ref, SEED, VEHICLE)
        assert np.array_equal(a.quaternion, b.quaternion) and a.specific_force_mps2 == b.specific_force_mps2
        # second order in the (~0.01 rad) tilt
        angle = 2 * math.asin(min(1.0, np.linalg.norm(rotations.multiply(rotations.conjugate(a.quaternion),
                                                                           c.quaternion)[:3])))
        assert angle < 1e-3  # 0.06 deg: products of the 0.01-level errors
        assert math.isclose(a.specific_force_mps2, c.specific_force_mps2, rel_tol=1e-4)


# --- limits and bad input ---------------------------------------------------------------------

def test_thrust_and_tilt_saturation_reported():
    sp, sat = pd(_state(position=(0, 0, -10)), _ref(), SEED, VEHICLE)  # 11 m low: u1 far above the maximum
    assert sat.thrust and math.isclose(sp.specific_force_mps2 * M, VEHICLE.thrust_max_n)
    sp, sat = pd(_state(position=(0, 0, 10)), _ref(), SEED, VEHICLE)   # far too high: u1 < 0 -> minimum
    assert sat.thrust and sp.specific_force_mps2 * M == VEHICLE.thrust_min_n
    for law in (pd, se3):
        sp, sat = law(_state(position=(-5, 3, 1)), _ref(), SEED, VEHICLE)
        max_tilt_rad = math.radians(VEHICLE.max_tilt_deg)  # pd clips |(roll, pitch)|, whose tilt is a bit less
        assert sat.tilt and 0.98 * max_tilt_rad < _tilt_rad(sp.quaternion) <= max_tilt_rad + 1e-12
        sp, sat = law(_state(), _ref(), SEED, VEHICLE, limits=Limits.of(VEHICLE, max_tilt_deg=10.0))
        assert not sat.any


def test_se3_keeps_the_azimuth_when_asked_to_fall_faster_than_gravity():
    sp, sat = se3(_state(), _ref(acceleration=(1.0, 0, -20.0)), SEED, VEHICLE)
    body_z = rotations.to_matrix(sp.quaternion)[:, 2]
    assert sat.tilt and body_z[0] > 0 and abs(body_z[1]) < 1e-12 and np.all(np.isfinite(body_z))


@pytest.mark.parametrize('field,owner', [('position', 'state'), ('quaternion', 'state'), ('jerk', 'reference'),
                                         ('yaw', 'reference')])
def test_non_finite_input_raises_naming_the_field(field, owner):
    state, ref = _state(), _ref()
    target = state if owner == 'state' else ref
    value = getattr(target, field)
    setattr(target, field, math.nan if np.isscalar(value) else np.full_like(value, math.nan))
    for law in (pd, se3):
        with pytest.raises(ValueError, match=f'{owner}.{field}'):
            law(state, ref, SEED, VEHICLE)
    with pytest.raises(ValueError):
        PositionController('pid', SEED, VEHICLE).update(state, ref, 0.01)


def test_finite_values_whose_sum_overflows_are_accepted():
    """The finiteness check sums the values; a sum that overflows is not a non-finite input."""
    big = 1e308
    state, ref = _state(position=(big, big, big)), _ref(position=(big, big, big))
    sp, _ = pd(state, ref, SEED, VEHICLE)
    assert np.all(np.isfinite(sp.quaternion))


def _seed_law_in_numpy(state, ref, gains, limits, integral=None):
    """Eq. 1-5 on numpy 3-vectors, the vectorized form of the law: (quaternion, specific force, tilt clipped,
    thrust clipped)."""
    acc = gains.kp * (ref.position - state.position) + gains.kd * (ref.velocity - state.velocity)
    if gains.use_feedforward:
        acc = acc + ref.acceleration
        if np.any(gains.drag_feedforward_per_s):
            acc = acc + gains.drag_feedforward_per_s * ref.velocity
    if integral is not None:
        acc = acc + gains.ki * integral
    s, c = np.sin(ref.yaw), np.cos(ref.yaw)
    roll, pitch = (acc[0] * s - acc[1] * c) / G, (acc[0] * c + acc[1] * s) / G
    tilt = np.hypot(roll, pitch)
    if tilt > limits.max_tilt_rad:
        roll, pitch = roll * limits.max_tilt_rad / tilt, pitch * limits.max_tilt_rad / tilt
    thrust = M * G + M * acc[2]
    clamped = min(max(thrust, limits.thrust_min_n), limits.thrust_max_n)
    return rotations.from_euler(roll, pitch, ref.yaw), clamped / M, tilt > limits.max_tilt_rad, clamped != thrust


@pytest.mark.parametrize('controller', ['pd', 'pid'])
def test_seed_law_equals_its_numpy_form_bit_for_bit(controller):
    """The per-tick law in scalar arithmetic gives exactly what eq. 1-5 on numpy vectors give (random states,
    references, yaws, drag feed-forward on and off, tilt and thrust clipped or not)."""
    rng = np.random.default_rng(7)
    limits = Limits.of(VEHICLE)
    for k in range(2000):
        gains = PositionGains(drag_feedforward_per_s=[0.0, 0.35][k % 2], use_feedforward=k % 5 != 0)
        q = rng.normal(size=4)
        state = State(position=rng.normal(size=3) * 3, velocity=rng.normal(size=3) * 2,
                      quaternion=q / np.linalg.norm(q), body_rates=rng.normal(size=3))
        ref = Reference(position=rng.normal(size=3) * 3, velocity=rng.normal(size=3) * 2,
                        acceleration=rng.normal(size=3) * 4, jerk=rng.normal(size=3), yaw=float(rng.uniform(-7, 7)),
                        yaw_rate=float(rng.normal()))
        integral = rng.normal(size=3) * 0.05 if controller == 'pid' else None
        sp, sat = _law(controller)(state, ref, gains, VEHICLE, integral=integral)
        quaternion, force, tilt, thrust = _seed_law_in_numpy(state, ref, gains, limits, integral)
        assert np.array_equal(sp.quaternion, quaternion) and sp.specific_force_mps2 == force
        assert (sat.tilt, sat.thrust) == (tilt, thrust)
        assert np.array_equal(sp.body_rates, [0.0, 0.0, ref.yaw_rate])


def test_unknown_controller_named():
    with pytest.raises(ValueError, match="'lqr'"):
        PositionController('lqr', SEED, VEHICLE)


def test_pid_integral_clamp_and_reset():
    ctl = PositionController('pid', SEED, VEHICLE)
    ref = _ref(position=(0.0, 0.0, 1.1))
    sp, sat = ctl.update(_state(), ref, 0.01)
    assert np.allclose(ctl.integral_m_s, [0, 0, 0.001]) and not sat.integral
    # eq. 2 with the integral: u1 = m (g + kp e + ki I)
    assert math.isclose(sp.specific_force_mps2, G + 20 * 0.1 + 10 * 0.001, rel_tol=1e-12)
    for _ in range(1000):
        sp, sat = ctl.update(_state(), ref, 0.01)
    assert sat.integral and math.isclose(SEED.ki[2] * ctl.integral_m_s[2], SEED.integral_limit_mps2)
    ctl.reset()
    assert np.all(ctl.integral_m_s == 0)


# --- SE(3) body-rate feed-forward -------------------------------------------------------------

def _circle(t, radius=1.0, w=1.0, yaw_rate=0.3):
    c, s = math.cos(w * t), math.sin(w * t)
    return _ref(position=(radius * c, radius * s, 1.0), velocity=(-radius * w * s, radius * w * c, 0),
                acceleration=(-radius * w * w * c, -radius * w * w * s, 0),
                jerk=(radius * w ** 3 * s, -radius * w ** 3 * c, 0), yaw=yaw_rate * t, yaw_rate=yaw_rate)


def test_se3_feedforward_rates_match_the_attitude_derivative():
    """On the reference, omega_des = vee(R_des^T dR_des/dt) (central difference of the commanded attitude)."""
    h = 1e-5
    for t in (0.0, 0.7, 2.0):
        sps = [se3(_state(position=_circle(tt).position, velocity=_circle(tt).velocity), _circle(tt), SEED,
                   VEHICLE)[0] for tt in (t - h, t, t + h)]
        r0, r1, r2 = (rotations.to_matrix(sp.quaternion) for sp in sps)
        omega = rotations.vee(r1.T @ (r2 - r0) / (2 * h))
        assert np.allclose(sps[1].body_rates, omega, atol=1e-6)


# --- closed loop on an ideal rigid body (perfect attitude tracking) ---------------------------

def simulate(law, ref_fn, p0, v0, t_end_s, mass_true_kg=M, dt_s=0.005, integral=False):
    """RK4 of  p'' = (u1 / m_true) R(q_des) e3 - g e3  (attitude follows the setpoint instantly).

    With `integral`, the pid integral I' = r_T - r is part of the integrated state.
    """
    def deriv(t, x):
        state = _state(position=x[0:3], velocity=x[3:6])
        ref = ref_fn(t)
        for _ in range(2):  # perfect attitude tracking: the vehicle is at the attitude it is commanded
            sp, _ = pid(state, ref, SEED, VEHICLE, integral=x[6:9]) if integral else law(state, ref, SEED, VEHICLE)
            state.quaternion = sp.quaternion
        thrust_n = sp.specific_force_mps2 * M
        acc = thrust_n / mass_true_kg * rotations.to_matrix(sp.quaternion)[:, 2] - [0, 0, G]
        return np.concatenate([x[3:6], acc, ref.position - x[0:3]])

    x = np.concatenate([p0, v0, np.zeros(3)])
    times = np.arange(0.0, t_end_s + dt_s / 2, dt_s)
    out = [x.copy()]
    for t in times[:-1]:
        k1 = deriv(t, x)
        k2 = deriv(t + dt_s / 2, x + dt_s / 2 * k1)
        k3 = deriv(t + dt_s / 2, x + dt_s / 2 * k2)
        k4 = deriv(t + dt_s, x + dt_s * k3)
        x = x + dt_s / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        out.append(x.copy())
    return times, np.array(out)


def linear_error(t, e0, kp, kd):
    """e'' + kd e' + kp e = 0, e(0) = e0, e'(0) = 0 (overdamped for the seed's gains)."""
    disc = math.sqrt(kd * kd - 4 * kp)
    r1, r2 = (-kd + disc) / 2, (-kd - disc) / 2
    return e0 * (r2 * np.exp(r1 * t) - r1 * np.exp(r2 * t)) / (r2 - r1)


@pytest.mark.parametrize('law', [pd, se3])
def test_step_response_follows_linear_analysis(law):
    hover = lambda t: _ref()  # noqa: E731
    t, x = simulate(law, hover, [0.1, 0.0, 1.0], [0, 0, 0], 4.0)   # x step: kp 5, kd 5
    assert np.max(np.abs(x[:, 0] - linear_error(t, 0.1, 5, 5))) < 2e-4        # 0.2 % of the step
    t, x = simulate(law, hover, [0.0, 0.0, 1.2], [0, 0, 0], 3.0)   # z step: kp 20, kd 10, exact in z
    assert np.max(np.abs(x[:, 2] - 1.0 - linear_error(t, 0.2, 20, 10))) < 1e-6
    assert abs(x[-1, 2] - 1.0) < 1e-3


def test_trajectory_tracking_errors_converge_as_predicted():
    """A 1 m circle at 1 rad/s started 0.1 m off: the error decays as e'' + 5 e' + 5 e = 0."""
    p0 = _circle(0).position + [0.1, 0, 0]
    for law, tol_m in ((se3, 1e-6), (pd, 5e-3)):   # se3 is exact; pd's small-angle eq. 2-4 leave mm
        t, x = simulate(law, _circle, p0, _circle(0).velocity, 6.0)
        error = x[:, :3] - np.array([_circle(tt).position for tt in t])
        predicted = np.stack([linear_error(t, 0.1, 5, 5), 0 * t, 0 * t], axis=1)
        assert np.max(np.abs(error - predicted)) < tol_m
    assert abs(predicted[-1, 0]) < 1e-4  # and the prediction itself has converged


def test_integral_removes_the_mass_mismatch_error_pd_does_not():
    """Vehicle 10 % heavier than the controller believes (the seed's Figure 5: hovering low)."""
    hover = lambda t: _ref()  # noqa: E731
    mass_true = 1.1 * M
    _, x_pd = simulate(pd, hover, [0, 0, 1.0], [0, 0, 0], 20.0, mass_true, dt_s=0.01)
    _, x_pid = simulate(None, hover, [0, 0, 1.0], [0, 0, 0], 20.0, mass_true, dt_s=0.01, integral=True)
    # PD equilibrium: (m / 1.1m)(g + kp_z e) = g  ->  e = 0.1 g / kp_z below the reference
    assert math.isclose(1.0 - x_pd[-1, 2], 0.1 * G / 20.0, rel_tol=1e-3)
    assert abs(1.0 - x_pid[-1, 2]) < 1e-3


# --- attitude law options ---------------------------------------------------------------------

@pytest.mark.parametrize('law', ['pd', 'se3'])
def test_attitude_lead_tilts_by_lead_times_jerk_and_leaves_thrust(law):
    ref = _ref(acceleration=(1.0, 0, 0), jerk=(4.0, 0, 0))
    plain = PositionController(law, SEED, VEHICLE).update(_state(), ref, 0.01)[0]
    led = PositionController(law, replace(SEED, attitude_lead_s=0.1), VEHICLE).update(_state(), ref, 0.01)[0]
    pitch_plain, pitch_led = rotations.to_euler(plain.quaternion)[1], rotations.to_euler(led.quaternion)[1]
    # the attitude is that of a_x = 1 + 0.1 * 4 = 1.4 m/s^2 instead of 1.0
    expected = (1.4 / G, 1.0 / G) if law == 'pd' else (math.atan(1.4 / G), math.atan(1.0 / G))
    assert (pitch_led, pitch_plain) == pytest.approx(expected, abs=1e-9)
    assert led.specific_force_mps2 == pytest.approx(plain.specific_force_mps2, abs=1e-12)


@pytest.mark.parametrize('law', ['pd', 'se3'])
def test_attitude_lead_leads_the_drag_feedforward_too(law):
    """The attitude is led to the whole feed-forward `lead` later: (a_T + D v_T)' = j_T + D a_T, so with drag D the
    tilt is that of a_x = a_T + D v_T + lead (j_T + D a_T); the thrust is not led."""
    ref = _ref(velocity=(0.5, 0, 0), acceleration=(1.0, 0, 0), jerk=(4.0, 0, 0))
    state = _state(velocity=(0.5, 0, 0))
    gains = replace(SEED, attitude_lead_s=0.1, drag_feedforward_per_s=2.0)
    led = PositionController(law, gains, VEHICLE).update(state, ref, 0.01)[0]
    unled = PositionController(law, replace(gains, attitude_lead_s=0.0), VEHICLE).update(state, ref, 0.01)[0]
    a_x = 1.0 + 2.0 * 0.5 + 0.1 * (4.0 + 2.0 * 1.0)   # 2.6 m/s^2
    expected = a_x / G if law == 'pd' else math.atan(a_x / G)
    assert rotations.to_euler(led.quaternion)[1] == pytest.approx(expected, abs=1e-9)
    assert led.specific_force_mps2 == pytest.approx(unled.specific_force_mps2, abs=1e-12)


@pytest.mark.parametrize('law', ['pd', 'pid', 'se3'])
def test_drag_feedforward_adds_drag_times_the_plan_velocity_and_only_with_feedforward(law):
    """On the plan (no error), a_des = a_T + D v_T: a command identical to one asking for that acceleration."""
    v_t = np.array([0.8, -0.4, 0.2])
    state = _state(velocity=v_t)
    fed = PositionController(law, replace(SEED, drag_feedforward_per_s=1.0), VEHICLE).update(
        state, _ref(velocity=v_t), 0.01)[0]
    asked = PositionController(law, SEED, VEHICLE).update(state, _ref(velocity=v_t, acceleration=1.0 * v_t), 0.01)[0]
    assert np.allclose(fed.quaternion, asked.quaternion, atol=1e-12)
    assert fed.specific_force_mps2 == pytest.approx(asked.specific_force_mps2, abs=1e-12)
    off = replace(SEED, drag_feedforward_per_s=1.0, use_feedforward=False)
    plain = replace(SEED, use_feedforward=False)
    assert np.allclose(PositionController(law, off, VEHICLE).update(state, _ref(velocity=v_t), 0.01)[0].quaternion,
                       PositionController(law, plain, VEHICLE).update(state, _ref(velocity=v_t), 0.01)[0].quaternion)


def test_disturbance_observer_converges_to_a_constant_external_acceleration():
    """A level vehicle at hover thrust whose velocity grows by d dt per step: the observer estimates d (first
    order, time constant tau), and the command then asks for -d on top of eq. 1."""
    gains = replace(SEED, kp=np.zeros(3), kd=np.zeros(3), disturbance_time_constant_s=0.05)
    ctl = PositionController('se3', gains, VEHICLE)
    d, dt, v = np.array([0.6, -0.3, 0.0]), 0.01, np.zeros(3)
    for _ in range(100):   # 1 s = 20 tau; the command is ignored (the plant is the scripted one)
        sp, _ = ctl.update(_state(velocity=v), _ref(), dt)
        thrust_before = ctl._previous[2]
        v = v + d * dt + (thrust_before - G) * dt * np.array([0, 0, 1.0])
    assert ctl.disturbance_mps2 == pytest.approx(d, abs=1e-6)
    tilt_from_command = rotations.to_matrix(sp.quaternion)[:2, 2] * sp.specific_force_mps2
    assert tilt_from_command == pytest.approx(-d[:2], abs=3e-3)  # thrust along the current (level) body z
    ctl.reset()
    assert not ctl.disturbance_mps2.any()


def test_speed_extensions_are_off_by_default():
    assert SEED.attitude_lead_s == 0.0 and SEED.disturbance_time_constant_s == 0.0


@pytest.mark.parametrize('controller', ['pd', 'pid', 'se3'])
def test_thrust_scale_divides_the_thrust_command_only(controller):
    """A vehicle delivering 0.94 of the command (identify's thrust_scale) is asked for 1 / 0.94 of it."""
    state, ref = _state(position=(0.1, -0.2, 0.9)), _ref()
    plain, _ = PositionController(controller, SEED, VEHICLE).update(state, ref, 0.01)
    scaled, _ = PositionController(controller, replace(SEED, thrust_scale=0.94), VEHICLE).update(state, ref, 0.01)
    assert scaled.specific_force_mps2 == pytest.approx(plain.specific_force_mps2 / 0.94, rel=1e-12)
    assert np.allclose(scaled.quaternion, plain.quaternion, atol=1e-15)
