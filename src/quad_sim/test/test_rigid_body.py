"""The plant against closed forms and invariants."""

import math

import numpy as np
import pytest

from quad_common import rotations
from quad_common.types import GRAVITY_MPS2
from quad_sim.mixer import Mixer
from quad_sim.rigid_body import RigidBody


def _state(position=(0, 0, 0), velocity=(0, 0, 0), quaternion=(0, 0, 0, 1), rates=(0, 0, 0), rotors=(0, 0, 0, 0)):
    return [*map(float, position), *map(float, velocity), *map(float, quaternion), *map(float, rates),
            *map(float, rotors)]


def _run(body, x, w_cmd, dt, steps, **kw):
    for _ in range(steps):
        x = body.step(x, w_cmd, dt, **kw)
    return x


def test_pure_yaw_moment_spins_only_about_z(instant_motors):
    v = instant_motors
    mz = 2e-4
    w, flags = Mixer(v).rotor_speeds(v.hover_thrust_n, (0.0, 0.0, mz))
    assert flags == ()
    body = RigidBody(v)
    x = _run(body, _state(position=(0, 0, 1), rotors=w), w, 1e-3, 500)
    assert x[10] == pytest.approx(0.0, abs=1e-12) and x[11] == pytest.approx(0.0, abs=1e-12)
    assert x[12] == pytest.approx(mz / v.inertia_kgm2[2] * 0.5, rel=1e-9)
    assert np.allclose(x[0:6], [0, 0, 1, 0, 0, 0], atol=1e-9)
    roll, pitch, yaw = rotations.to_euler(x[6:10])
    assert abs(roll) < 1e-12 and abs(pitch) < 1e-12
    assert yaw == pytest.approx(0.5 * mz / v.inertia_kgm2[2] * 0.5 ** 2, rel=1e-9)


def test_free_fall_when_rotors_stop(instant_motors):
    body = RigidBody(instant_motors)
    x = _run(body, _state(position=(1, 2, 10), velocity=(0.5, 0, 0)), [0.0] * 4, 1e-3, 300)
    t = 0.3
    assert x[0] == pytest.approx(1 + 0.5 * t, abs=1e-12)
    assert x[2] == pytest.approx(10 - 0.5 * GRAVITY_MPS2 * t * t, abs=1e-10)
    assert x[5] == pytest.approx(-GRAVITY_MPS2 * t, abs=1e-10)


def test_energy_and_momentum_conserved_without_gravity(crazyflie):
    """Torque-free tumbling (gravity cancelled by an external m g): |L|, rotational energy, momentum kept."""
    v = crazyflie
    body = RigidBody(v)
    inertia = np.diag(v.inertia_kgm2)
    x = _state(velocity=(0.3, -0.2, 0.1), quaternion=rotations.from_euler(0.3, -0.2, 1.0), rates=(5.0, -3.0, 8.0))
    lift = (0.0, 0.0, v.mass_kg * GRAVITY_MPS2)

    def invariants(x):
        R, omega = rotations.to_matrix(x[6:10]), np.array(x[10:13])
        return R @ inertia @ omega, 0.5 * omega @ inertia @ omega, np.array(x[3:6])

    L0, E0, p0 = invariants(x)
    x = _run(body, x, [0.0] * 4, 1e-3, 2000, force_world=lift)
    L1, E1, p1 = invariants(x)
    assert np.allclose(L1, L0, rtol=0, atol=1e-9 * np.linalg.norm(L0))
    assert E1 == pytest.approx(E0, rel=1e-9)
    assert np.allclose(p1, p0, atol=1e-12)
    assert np.linalg.norm(x[6:10]) == pytest.approx(1.0, abs=1e-14)


def test_rk4_converges_at_fourth_order(crazyflie):
    """Error against a fine reference shrinks ~16x per halving of the step (rotor lag + tumbling + thrust)."""
    body = RigidBody(crazyflie)
    x0 = _state(position=(0, 0, 1), quaternion=rotations.from_euler(0.2, 0.1, 0.3), rates=(3.0, -2.0, 1.0),
                rotors=(1500, 1700, 1900, 1600))
    w_cmd = [2000.0, 1500.0, 1800.0, 1700.0]
    T = 0.064

    def final(dt):
        return np.array(_run(body, list(x0), w_cmd, dt, int(round(T / dt))))

    reference = final(T / 512)
    errors = [np.linalg.norm((final(T / n) - reference)[:13]) for n in (16, 32, 64)]
    ratios = [errors[0] / errors[1], errors[1] / errors[2]]
    assert all(12 < r < 20 for r in ratios), (errors, ratios)


def test_hover_rotor_speed_closed_form(crazyflie):
    w = math.sqrt(crazyflie.mass_kg * GRAVITY_MPS2 / (4 * crazyflie.k_eta))
    x = _state(position=(0, 0, 1), rotors=[w] * 4)
    assert np.allclose(RigidBody(crazyflie).derivative(x, [w] * 4)[3:], 0.0, atol=1e-12)
