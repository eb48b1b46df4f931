import pytest

from quad_common.testing import isolated_domain


@pytest.fixture
def ros_env():
    """Environment for subprocesses of one test graph: its own ROS domain, localhost discovery."""
    with isolated_domain() as (_, env):
        yield env
