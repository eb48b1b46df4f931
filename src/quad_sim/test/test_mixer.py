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
