import pytest
from vehicle_emu_client import EmulatedVehicle
from xdist_groups import pytest_collection_modifyitems  # noqa: F401  (the hook, found here by name)

from quad_common.ros.testing import isolated_domain


@pytest.fixture
def ros_env():
    """Environment for subprocesses of one test graph: its own ROS domain, localhost discovery."""
    with isolated_domain() as (_, env):
        yield env


@pytest.fixture
def vehicles(tmp_path):
    """start(*args, **kwargs) -> an EmulatedVehicle (vehicle_emu_client) for the test; every one closed after."""
    started = []

    def start(*args, **kwargs):
        v = EmulatedVehicle(tmp_path, *args, **kwargs)
        started.append(v)
        return v
    yield start
    for v in started:
        v.close()
