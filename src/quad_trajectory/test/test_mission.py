"""Mission files: the shipped missions plan collision-free at the seed's 0.5 m/s and at 2 m/s; bad files are named."""

import glob
import os

import numpy as np
import pytest

from quad_trajectory.mission import DEFAULT_MISSION_PATH, load_mission, plan_mission

MISSIONS_DIR = os.path.dirname(DEFAULT_MISSION_PATH)
SHIPPED = sorted(glob.glob(os.path.join(MISSIONS_DIR, '*.yaml')))


def test_the_expected_missions_ship():
    names = {os.path.basename(p) for p in SHIPPED}
    assert {'maze.yaml', 'figure8.yaml', 'stop_every_waypoint.yaml', 'long_100.yaml', 'window.yaml'} <= names


@pytest.mark.parametrize('path', SHIPPED, ids=os.path.basename)
@pytest.mark.parametrize('speed_mps', [0.5, 2.0])
def test_shipped_mission_plans_collision_free(path, speed_mps):
    mission = load_mission(path)
    assert np.all(mission.waypoints[:, 2] >= 0.5)                 # hover height
    np.testing.assert_array_equal(mission.initial_position, mission.waypoints[0])
    assert mission.vehicle is not None and mission.vehicle.name == 'crazyflie'
    result = plan_mission(mission, speed_mps=speed_mps)
    traj = result.trajectory
    np.testing.assert_allclose(traj.evaluate(result.waypoint_times_s())[:, :3], result.waypoints, atol=1e-9)
    if mission.world is not None:
        t = np.linspace(0, traj.duration_s, int(traj.duration_s * 2000))
        assert not mission.world.collides(traj.evaluate(t)[:, :3], mission.options.robot_radius_m).any()


def test_default_maze_scale_and_speed_override():
    mission = load_mission(DEFAULT_MISSION_PATH)
    assert mission.world is not None and len(mission.world.blocks) >= 2
    slow, fast = plan_mission(mission), plan_mission(mission, speed_mps=2.0)
    assert 4.0 <= slow.trajectory.arc_length() <= 10.0
    polyline = np.linalg.norm(np.diff(mission.waypoints, axis=0), axis=1).sum()
    assert slow.trajectory.duration_s == pytest.approx(polyline / 0.5)
    assert fast.trajectory.duration_s == pytest.approx(polyline / 2.0)
    assert fast.trajectory.max_acceleration() < 7.0    # within the Crazyflie's 35 degree tilt (g tan 35 = 6.9)


def test_long_mission_and_json_world():
    assert len(load_mission(os.path.join(MISSIONS_DIR, 'long_100.yaml')).waypoints) >= 100
    window = load_mission(os.path.join(MISSIONS_DIR, 'window.yaml'))
    assert window.world_path.endswith('.json') and len(window.world.blocks) == 4
    stop = load_mission(os.path.join(MISSIONS_DIR, 'stop_every_waypoint.yaml'))
    assert stop.options.waypoint_constraint == 'stop' and stop.options.method == 'minsnap'


def test_paths_are_relative_to_the_mission_file(tmp_path):
    (tmp_path / 'worlds').mkdir()
    (tmp_path / 'worlds' / 'w.yaml').write_text('bounds: {extents: [-1, 3, -1, 3, 0, 3]}\nblocks: []\n')
    (tmp_path / 'm').mkdir()
    (tmp_path / 'm' / 'x.yaml').write_text(
        'waypoints: [[0, 0, 1], [1, 0, 1]]\nworld: ../worlds/w.yaml\n'
        'trajectory: {method: minjerk, control_points: true, limits: {v_max_mps: 1.0}}\nfly_extra: 3\n')
    mission = load_mission(tmp_path / 'm' / 'x.yaml')
    assert mission.world_path == str(tmp_path / 'worlds' / 'w.yaml')
    assert mission.options.control_points == (0.1, 0.9) and mission.options.v_max_mps == 1.0
    assert mission.extra == {'fly_extra': 3}
    assert mission.name == 'x'


@pytest.mark.parametrize('text,words', [
    ('waypoints: [[0, 0, 1]]\n', 'at least two distinct'),
    ('yaw: 0\n', 'waypoints is missing'),
    ('waypoints: [[0, 0, 1], [1, 0, 1]]\ntrajectory: {methd: minsnap}\n', 'trajectory.methd is not a known key'),
    ('waypoints: [[0, 0, 1], [1, 0, 1]]\ntrajectory: {method: fast}\n', "method = 'fast'"),
    ('waypoints: [[0, 0, 1], [1, 0, 1]]\ntrajectory: {speed: 0}\n', 'speed = 0'),
    ('waypoints: [[0, 0, 1], [1, 0, 1]]\nworld: nowhere.json\n', 'nowhere.json: file not found'),
    ('waypoints: [[0, 0, 1], [1, 0, 1]]\ntrajectory: {limits: {vmax: 1}}\n', 'trajectory.limits'),
    ('waypoints: [[0, 0, 1], [1, 0, 1]]\ntrajectory: {limits: {a_max_mps2: 99}}\n', 'cannot be met'),
])
def test_bad_mission_names_file_field_and_value(tmp_path, text, words):
    path = tmp_path / 'bad.yaml'
    path.write_text(text)
    with pytest.raises(ValueError, match=words) as info:
        load_mission(path)
    assert str(path) in str(info.value)


def test_plan_mission_refuses_unknown_override():
    with pytest.raises(ValueError, match="unknown option 'sped'"):
        plan_mission(load_mission(DEFAULT_MISSION_PATH), sped=1.0)
