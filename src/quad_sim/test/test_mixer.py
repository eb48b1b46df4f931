import dataclasses

import numpy as np
import pytest

from quad_sim.mixer import ROLL_PITCH, THRUST, YAW, Mixer


@pytest.mark.parametrize('layout', ['x', 'plus'])
def test_round_trip_inside_limits(crazyflie, layout):
    mixer = Mixer(dataclasses.replace(crazyflie, layout=layout))
    rng = np.random.default_rng(3)
    for _ in range(50):
        u = np.array([rng.uniform(0.25, 0.4), *rng.uniform(-2e-3, 2e-3, 2), rng.uniform(-5e-4, 5e-4)])
        w, flags = mixer.rotor_speeds(u[0], u[1:])
        assert flags == ()
        assert np.allclose(mixer.wrench(w), u, rtol=1e-9, atol=1e-15)


def test_yaw_gives_way_first(crazyflie):
    mixer = Mixer(crazyflie)
    request = np.array([crazyflie.hover_thrust_n, 1e-3, -5e-4, 1e-2])  # far more yaw than the rotors have
    w, flags = mixer.rotor_speeds(request[0], request[1:])
    got = mixer.wrench(w)
    assert flags == (YAW,)
    assert np.allclose(got[:3], request[:3], rtol=1e-9)
    assert 0 < got[3] < request[3]
    assert np.all(np.asarray(w) <= crazyflie.rotor_speed_max_radps + 1e-9)


def test_thrust_shifts_to_keep_roll_pitch(crazyflie):
    mixer = Mixer(crazyflie)
    w, flags = mixer.rotor_speeds(crazyflie.thrust_max_n, (2e-3, 0.0, 0.0))  # full thrust + roll
    got = mixer.wrench(w)
    assert THRUST in flags and ROLL_PITCH not in flags
    assert got[1] == pytest.approx(2e-3, rel=1e-9) and got[0] < crazyflie.thrust_max_n


def test_roll_pitch_scaled_only_beyond_rotor_range(crazyflie):
    mixer = Mixer(crazyflie)
    w, flags = mixer.rotor_speeds(crazyflie.hover_thrust_n, (1.0, 0.0, 0.0))
    assert ROLL_PITCH in flags
    assert np.min(w) == pytest.approx(0.0, abs=1e-6) and np.max(w) == pytest.approx(2500.0, rel=1e-9)


def test_full_thrust_keeps_a_yaw_margin_bought_from_thrust(crazyflie):
    """PX4's MINIMUM_YAW_MARGIN: at full thrust yaw still acts, the thrust gives way, roll/pitch stays exact."""
    mixer = Mixer(crazyflie)
    request = np.array([crazyflie.thrust_max_n, 2e-4, -1e-4, 2e-3])
    w, flags = mixer.rotor_speeds(request[0], request[1:])
    got = mixer.wrench(w)
    assert THRUST in flags and ROLL_PITCH not in flags
    assert np.allclose(got[1:3], request[1:3], rtol=1e-9)
    assert got[3] > 0.2 * request[3]                   # the old mixer gave no yaw at all here
    f_range = mixer.f_max_n - mixer.f_min_n
    assert crazyflie.thrust_max_n - got[0] <= 4 * 0.15 * f_range + 1e-12
    assert np.all(np.asarray(w) <= crazyflie.rotor_speed_max_radps + 1e-9)


def test_yaw_demand_is_limited(crazyflie):
    mixer = Mixer(crazyflie)
    w, flags = mixer.rotor_speeds(crazyflie.hover_thrust_n, (0.0, 0.0, 1.0))  # 1 N m: absurd for a Crazyflie
    got = mixer.wrench(w)
    assert flags == (YAW,)
    assert got[3] == pytest.approx(mixer.yaw_limit_nm, rel=1e-9)
    assert got[0] == pytest.approx(crazyflie.hover_thrust_n, rel=1e-9) and np.allclose(got[1:3], 0.0, atol=1e-12)


def test_yaw_never_takes_roll_pitch(crazyflie):
    mixer = Mixer(crazyflie)
    rng = np.random.default_rng(7)
    for _ in range(300):
        u = np.array([rng.uniform(0.0, crazyflie.thrust_max_n), *rng.uniform(-1.5e-3, 1.5e-3, 2),
                      rng.uniform(-3e-3, 3e-3)])
        w, flags = mixer.rotor_speeds(u[0], u[1:])
        got = mixer.wrench(w)
        if ROLL_PITCH not in flags:
            assert np.allclose(got[1:3], u[1:3], rtol=1e-7, atol=1e-12)
        assert got[3] * u[3] >= -1e-15 and abs(got[3]) <= abs(u[3]) + 1e-12   # yaw only ever reduced
        if THRUST not in flags:
            assert got[0] == pytest.approx(u[0], rel=1e-9)
