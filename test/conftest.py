import pytest
from vehicle_emu_client import EmulatedVehicle

from quad_common.testing import isolated_domain

SHARED_SCOPES = ('class', 'module', 'package')


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """The tests of a file that use a fixture wider than one test (a module-scoped flight, an identified model) form
    one xdist_group, so pytest-xdist's --dist loadgroup runs them on one worker and that fixture is set up once; every
    other test is scheduled on its own. (Before xdist's own hook, which reads the groups.)"""
    for item in items:
        if any(defs[-1].scope in SHARED_SCOPES for defs in item._fixtureinfo.name2fixturedefs.values()):
            item.add_marker(pytest.mark.xdist_group(item.nodeid.split('::')[0]))


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
