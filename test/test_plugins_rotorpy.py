"""rotorpy 3.0.0's own SE3Control, unchanged from its package (the peers' venv, bench/peers.py, installed on first
use), flown by quadflight's offline loop as a user class: it completes the mission within a centimetre, as it does
in rotorpy's own Environment.run (docs/benchmarks.md, bench/bench_plugins.py)."""

import sys

import pytest

from quad_bringup.closed_loop import LoopOptions, fly_offline
from quad_common.paths import REPO_ROOT, resolve_config
from quad_common.vehicle import load_vehicle
from quad_control.plugins import make_controller, vehicle_params

sys.path.insert(0, str(REPO_ROOT / 'bench'))
import bench_plugins  # noqa: E402


@pytest.fixture(scope='module')
def rotorpy_path(tmp_path_factory, request):
    path = bench_plugins.rotorpy_dir(tmp_path_factory.mktemp('rotorpy'))
    sys.path.insert(0, str(path))
    request.addfinalizer(lambda: sys.path.remove(str(path)))
    return path


def test_rotorpy_se3control_is_built_with_our_vehicle_params_and_flies_a_mission(rotorpy_path):
    vehicle = resolve_config('config/vehicles/crazyflie.yaml')
    control = make_controller(bench_plugins.SE3CONTROL, None, load_vehicle(vehicle))
    assert control.cls.__module__ == 'rotorpy.controllers.quadrotor_control'   # theirs, not a copy
    assert str(rotorpy_path) in sys.modules['rotorpy'].__path__[0]
    assert control.instance.mass == vehicle_params(load_vehicle(vehicle))['mass']
    window = resolve_config('config/missions/window.yaml')
    metrics = fly_offline(window, LoopOptions(controller=bench_plugins.SE3CONTROL))
    assert metrics['completed'] and not metrics['collided'] and 'stopped' not in metrics
    assert metrics['rmse_m'] < 0.01
