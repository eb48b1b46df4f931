"""rotorpy 3.0.0's own SE3Control, unchanged from its package (the peers' venv, quad_bringup.peers.peer_venv, installed
on first use), flown by quadflight's offline loop as a user class: it completes the mission within a centimetre, as it
does in rotorpy's own Environment.run (docs/benchmarks.md, bench/bench_plugins.py)."""

import sys

import pytest

from quad_bringup.offline.closed_loop import LoopOptions, fly_offline
from quad_bringup.peers.rotorpy_peer import SE3CONTROL, rotorpy_dir
from quad_common.paths import resolve_config
from quad_common.vehicle import load_vehicle
from quad_control.plugins import make_controller, vehicle_params


@pytest.fixture(scope='module')
def rotorpy_path(tmp_path_factory, request):
    path = rotorpy_dir(tmp_path_factory.mktemp('rotorpy'))
    sys.path.insert(0, str(path))
    request.addfinalizer(lambda: sys.path.remove(str(path)))
    return path


def test_rotorpy_se3control_is_built_with_our_vehicle_params_and_flies_a_mission(rotorpy_path):
    vehicle = resolve_config('config/vehicles/crazyflie.yaml')
    control = make_controller(SE3CONTROL, None, load_vehicle(vehicle))
    assert control.cls.__module__ == 'rotorpy.controllers.quadrotor_control'   # theirs, not a copy
    assert str(rotorpy_path) in sys.modules['rotorpy'].__path__[0]
    assert control.instance.mass == vehicle_params(load_vehicle(vehicle))['mass']
    window = resolve_config('config/missions/window.yaml')
    metrics = fly_offline(window, LoopOptions(controller=SE3CONTROL))
    assert metrics['completed'] and not metrics['collided'] and 'stopped' not in metrics
    assert metrics['rmse_m'] < 0.01


def _mission(tmp_path, waypoints, trajectory):
    path = tmp_path / 'rotorpy_trajectory.yaml'
    path.write_text(f'name: rotorpy_trajectory\nvehicle: {resolve_config("config/vehicles/crazyflie.yaml")}\n'
                    f'waypoints: {waypoints}\ntrajectory:\n' + ''.join(f'  {line}\n' for line in trajectory))
    return path


ROTORPY_TRAJECTORIES = {
    # rotorpy's MinSnap, built from the mission's waypoints as its constructor takes them
    'minsnap': ('[[0, 0, 1], [1, 0, 1], [1, 1, 1.2], [0, 1, 1]]',
                ['generator: rotorpy.trajectories.minsnap:MinSnap', 'generator_args: {v_avg: 0.5, verbose: false}',
                 'duration_s: 8.0']),
    # rotorpy's TwoDLissajous from its own arguments alone: one period of x (2 pi / a s), starting at the first waypoint
    'lissajous': ('[[0, 0, 1], [1, 0, 1]]',
                  ['generator: rotorpy.trajectories.lissajous_traj:TwoDLissajous', 'generator_waypoints: false',
                   'generator_args: {A: 1.0, B: 0.5, a: 0.5, b: 1.0, height: 1.0}', 'duration_s: 12.566']),
}


@pytest.mark.parametrize('name', sorted(ROTORPY_TRAJECTORIES))
def test_rotorpy_trajectory_classes_are_planned_exactly_and_flown_by_rotorpy_s_se3control(rotorpy_path, tmp_path,
                                                                                         name):
    """rotorpy's own trajectory classes, unchanged, as a mission's plan: the plan is the class's flat outputs at its
    samples and between them, it passes the feasibility check, and rotorpy's own SE3Control flies it through the
    offline loop (the whole rotorpy pair through quadflight)."""
    import numpy as np

    from quad_trajectory.generated import resolve
    from quad_trajectory.mission import load_mission, plan_mission, preflight

    waypoints, trajectory = ROTORPY_TRAJECTORIES[name]
    path = _mission(tmp_path, waypoints, trajectory)
    mission = load_mission(path)
    result = plan_mission(mission)
    assert resolve(mission.options.generator).__module__.startswith('rotorpy.trajectories')   # theirs, not a copy
    options = mission.options
    args = {k: (np.array(v, float) if isinstance(v, list) else v) for k, v in (options.generator_args or {}).items()}
    theirs = (resolve(options.generator)(np.array(mission.waypoints, float), **args) if options.generator_waypoints
              else resolve(options.generator)(**args))
    for t in (0.0, 0.731, 1.5, 2.345, 4.0):
        flat = theirs.update(t)
        assert np.allclose(result.trajectory.evaluate(t, 0)[:3], flat['x'], atol=1e-6)
        assert np.allclose(result.trajectory.evaluate(t, 1)[:3], flat['x_dot'], atol=1e-4)
    report = preflight(mission, result)
    assert report.ok, report.lines()
    metrics = fly_offline(path, LoopOptions(controller=SE3CONTROL))
    assert metrics['completed'] and not metrics['collided'] and 'stopped' not in metrics
    assert metrics['rmse_m'] < 0.05, metrics['rmse_m']   # the Lissajous starts at 0.7 m/s from a hover
