"""PX4 SIH's linear air drag on the emulated vehicle (quad_vehicle_emu.drag): none by default; asked for, the
vehicle decelerates at --drag-per-s per m/s (SIH_KDV / SIH_MASS, 1.0 by default on PX4 SIH)."""

import math
import os

import numpy as np
import pytest

from quad_common import rotations
from quad_common.types import GRAVITY_MPS2, AttitudeSetpoint
from quad_sim.simulator import Simulator
from quad_vehicle_emu.attitude import emulated_vehicle
from quad_vehicle_emu.drag import with_linear_drag

VEHICLE = os.path.join(os.path.dirname(__file__), '..', '..', '..', 'config', 'vehicles', 'px4_quad.yaml')


def _speed_after_tilting(per_s, tilt_deg=5.0, seconds=8.0):
    """Held tilted about y at tilt_deg with the thrust that holds the height: the speed it reaches."""
    vehicle, drag = with_linear_drag(emulated_vehicle(VEHICLE), per_s)
    sim = Simulator(vehicle, initial_position=(0.0, 0.0, 5.0), setpoint_timeout_s=1e6, disturbances=drag)
    sim.armed = True
    th = math.radians(tilt_deg)
    rot = np.array([[math.cos(th), 0.0, math.sin(th)], [0.0, 1.0, 0.0], [-math.sin(th), 0.0, math.cos(th)]])
    sim.set_setpoint(AttitudeSetpoint(quaternion=rotations.from_matrix(rot),
                                      specific_force_mps2=GRAVITY_MPS2 / math.cos(th), body_rates=None))
    sim.advance_steps(sim.steps_in(seconds))
    return sim.state.velocity


@pytest.mark.parametrize('per_s', [1.0, 0.5])
def test_the_vehicle_reaches_the_terminal_speed_of_its_linear_drag(per_s):
    """Accelerating at g tan(5 deg) = 0.86 m/s^2 against k v: it settles at 0.86 / k m/s (within 3 %) after
    8 s (8 and 4 time constants); without drag it would be at 6.9 m/s, still accelerating."""
    velocity = _speed_after_tilting(per_s)
    assert velocity[0] == pytest.approx(GRAVITY_MPS2 * math.tan(math.radians(5.0)) / per_s, rel=0.03)
    assert abs(velocity[2]) < 0.05


def test_no_drag_by_default():
    vehicle = emulated_vehicle(VEHICLE)
    assert with_linear_drag(vehicle, 0.0) == (vehicle, None)
    assert _speed_after_tilting(0.0)[0] > 6.0


@pytest.mark.parametrize('bad', [-0.1, float('nan'), 11.0])
def test_bad_drag_is_refused_naming_the_flag(bad):
    with pytest.raises(ValueError, match='--drag-per-s'):
        with_linear_drag(emulated_vehicle(VEHICLE), bad)
