import dataclasses
import os

import pytest

from quad_common.vehicle import load_vehicle

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), '..', '..', '..'))
CONFIG = os.path.join(ROOT, 'config')


@pytest.fixture
def crazyflie():
    return load_vehicle(os.path.join(CONFIG, 'vehicles', 'crazyflie.yaml'))


@pytest.fixture
def px4_quad():
    return load_vehicle(os.path.join(CONFIG, 'vehicles', 'px4_quad.yaml'))


@pytest.fixture
def instant_motors(crazyflie):
    """The Crazyflie with tau_m = 0: rotor speeds follow their commands within the step."""
    return dataclasses.replace(crazyflie, motor_time_constant_s=0.0)
