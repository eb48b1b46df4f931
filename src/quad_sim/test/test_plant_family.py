"""The plant family (config/plant_family.yaml): every member's onboard loop is stable for its own motor lag,
each kind of onboard attitude loop responds as its parameters say, and the plant-only errors act on the plant."""

import dataclasses
import os

import numpy as np
import pytest
from conftest import CONFIG

from quad_common import rotations
from quad_common.types import GRAVITY_MPS2, AttitudeSetpoint
from quad_common.vehicle import AttitudeLoop, load_vehicle, vehicle_from_dict
from quad_common.vehicle_file import load_plant_family
from quad_common.yaml_io import load_yaml
from quad_sim.attitude_poles import MIN_DAMPING_RATIO, attitude_damping
from quad_sim.simulator import Simulator

CRAZYFLIE = os.path.join(CONFIG, 'vehicles', 'crazyflie.yaml')
STEP_RAD = np.deg2rad(10.0)


def roll_step(vehicle, duration_s=1.5):
    """Times (s) and roll (rad) after a 10-degree roll step at hover thrust, high above the floor."""
    sim = Simulator(vehicle, initial_position=(0.0, 0.0, 20.0), setpoint_timeout_s=10.0)
    sim.set_setpoint(AttitudeSetpoint(quaternion=rotations.from_euler(STEP_RAD, 0.0, 0.0),
                                      specific_force_mps2=GRAVITY_MPS2 / np.cos(STEP_RAD)))
    times, roll = [], []
    for _ in range(int(round(duration_s / 0.005))):
        sim.advance(0.005)
        times.append(sim.time_s)
        roll.append(rotations.to_euler(sim.state.quaternion)[0])
    return np.array(times), np.array(roll)


def rise_time(times, roll, fraction=0.632):
    return float(times[np.argmax(roll >= fraction * STEP_RAD)])


@pytest.mark.parametrize('member', list(load_plant_family()))
def test_every_member_is_stable_for_its_own_motor_lag(member):
    vehicle = load_vehicle(CRAZYFLIE, plant=member)
    assert attitude_damping(vehicle) >= MIN_DAMPING_RATIO
    times, roll = roll_step(vehicle)
    late = roll[times > 1.0]
    assert abs(late.mean() - STEP_RAD) < 0.05 * STEP_RAD          # settles on the step
    assert late.max() - late.min() < 0.05 * STEP_RAD              # no ring left after 1 s
    assert roll.max() < 1.3 * STEP_RAD                            # overshoot under 30 %


def test_the_seed_gains_behind_72ms_motors_are_not_a_member():
    """What slow_motors_72ms retunes: the seed's eq. 6 behind 72 ms motors keeps damping ~0.03 and rings."""
    seed = load_vehicle(CRAZYFLIE)
    slow = dataclasses.replace(seed, motor_time_constant_s=0.072)
    assert attitude_damping(slow) < 0.05
    times, roll = roll_step(slow)
    late = roll[times > 1.0]
    assert late.max() - late.min() > 0.05 * STEP_RAD


def test_so3_pd_rises_like_its_angle_gain():
    """Cascade angle P -> rate P: with rate_p >> angle_p the response is ~first order with tau = 1 / angle_p."""
    vehicle = load_vehicle(CRAZYFLIE, plant='autopilot_so3')
    times, roll = roll_step(vehicle)
    expected_s = 1.0 / vehicle.attitude_loop.angle_p[0] + 1.0 / vehicle.attitude_loop.rate_p[0]
    assert rise_time(times, roll) == pytest.approx(expected_s, rel=0.2)
    faster = dataclasses.replace(vehicle, attitude_loop=dataclasses.replace(
        vehicle.attitude_loop, angle_p=np.array([13.0, 13.0, 2.8])))
    assert rise_time(*roll_step(faster)) < 0.7 * rise_time(times, roll)


def test_lag_loop_follows_its_time_constant():
    vehicle = load_vehicle(CRAZYFLIE, plant='autopilot_lag')
    inner_s = vehicle.attitude_gains.kd[0] / vehicle.attitude_gains.kp[0]   # eq. 6's own lag, ~0.1 s
    t63 = rise_time(*roll_step(vehicle))
    assert vehicle.attitude_loop.time_constant_s < t63 < vehicle.attitude_loop.time_constant_s + inner_s
    slower = dataclasses.replace(vehicle, attitude_loop=AttitudeLoop(type='lag', time_constant_s=0.3))
    assert rise_time(*roll_step(slower)) > t63 + 0.1


@pytest.mark.parametrize('member, expected_mps2', [('heavy_20pct', GRAVITY_MPS2 * (1 / 1.2 - 1)),
                                                   ('hover_thrust_error', -0.06 * GRAVITY_MPS2),
                                                   ('nominal', 0.0)])
def test_plant_errors_act_on_the_plant_only(member, expected_mps2):
    """The setpoint asks for hover (g) with the nominal mass; the plant's vertical acceleration shows the error."""
    vehicle = load_vehicle(CRAZYFLIE, plant=member)
    assert vehicle.mass_kg == pytest.approx(0.030)     # the controller's number is untouched
    sim = Simulator(vehicle, initial_position=(0.0, 0.0, 20.0), setpoint_timeout_s=10.0)
    sim.set_setpoint(AttitudeSetpoint(quaternion=rotations.from_yaw(0.0), specific_force_mps2=GRAVITY_MPS2))
    sim.advance(0.2)            # past the rotors' start from the plant's own hover speed
    v0 = sim.state.velocity[2]
    sim.advance(0.3)
    assert (sim.state.velocity[2] - v0) / 0.3 == pytest.approx(expected_mps2, abs=0.02)


def test_bad_plant_fields_are_named():
    base = load_yaml(CRAZYFLIE)
    for bad, words in (({'attitude_loop': {'type': 'pid'}}, 'attitude_loop.type'),
                       ({'attitude_loop': {'type': 'so3_pd', 'angle_p': [1, -2, 3]}}, 'angle_p'),
                       ({'attitude_loop': {'type': 'lag', 'time_constant_s': 0}}, 'time_constant_s'),
                       ({'attitude_loop': {'type': 'lag', 'tau': 0.1}}, 'tau'),
                       ({'mass_error': 3.0}, 'mass_error'),
                       ({'thrust_error': 'x'}, 'thrust_error')):
        with pytest.raises(ValueError, match=words):
            vehicle_from_dict({**base, **bad}, 'v')
    with pytest.raises(ValueError, match="'no_such_member'"):
        load_vehicle(CRAZYFLIE, plant='no_such_member')
    with pytest.raises(ValueError, match='mass_kg'):
        load_vehicle(CRAZYFLIE, plant={'mass_kg': 1.0})
