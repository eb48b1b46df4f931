"""Graph tests: `quadflight fly --controller package.module:Class` flies a user class through the ROS graph; one that
fails mid-flight never gives a bad setpoint, fly names it, and the simulator's failsafe has the vehicle."""

import json
import math
import os
import subprocess
from pathlib import Path

from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore
from test_fly import QUADFLIGHT, TIMEOUT_S, mission

ROOT = Path(__file__).resolve().parents[2]
USER_CONTROLLERS = ROOT / 'src' / 'quad_control' / 'test'   # user_controllers.py: classes that fail
FLIGHTSIM = 'quad_control.templates.flightsim_controller:SE3Control'


def _fly(tmp_path, env, controller, *extra):
    run_dir = tmp_path / 'run'
    path = mission(tmp_path, [[0, 0, 1], [0.8, 0.4, 1.2], [1.5, 0, 1]])
    env = dict(env, PYTHONPATH=f'{USER_CONTROLLERS}{os.pathsep}{env.get("PYTHONPATH", "")}')
    done = subprocess.run([QUADFLIGHT, 'fly', str(path), '--controller', controller, '--out', str(run_dir), '--quiet',
                           *extra], env=env, capture_output=True, text=True, timeout=TIMEOUT_S)
    return done, run_dir


def _setpoints(run_dir):
    """(stamp s, thrust/mass, quaternion) of every cmd/attitude_thrust in the bag."""
    ts = get_typestore(Stores.ROS2_JAZZY)
    with Reader(run_dir / 'bag') as reader:
        conns = [c for c in reader.connections if c.topic == 'cmd/attitude_thrust']
        out = []
        for c, _, raw in reader.messages(conns):
            msg = ts.deserialize_cdr(raw, c.msgtype)
            q = msg.orientation
            out.append((msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9, msg.linear_acceleration.z,
                        (q.x, q.y, q.z, q.w)))
    return out


def test_fly_flies_a_flightsim_style_user_class(tmp_path, ros_env):
    done, run_dir = _fly(tmp_path, ros_env, FLIGHTSIM)
    assert done.returncode == 0, done.stdout + done.stderr
    metrics = json.loads((run_dir / 'metrics.json').read_text())
    assert metrics['completed'] is True and metrics['controller'] == FLIGHTSIM
    assert metrics['rmse_m'] < 0.05
    assert run_dir.name == 'run' and 'flightsim_controller:SE3Control' in done.stdout


def test_a_user_class_that_raises_mid_flight_stops_the_setpoints_and_fly_names_it(tmp_path, ros_env):
    """user_controllers.Raises flies 0.5 s of its plan, then raises: no setpoint after that (all before finite),
    fly's verdict names the class and the line, exit 1."""
    done, run_dir = _fly(tmp_path, ros_env, 'user_controllers:Raises')
    out = done.stdout + done.stderr
    assert done.returncode == 1, out
    assert 'controller failed at t = ' in out and 'user_controllers.Raises.update raised ZeroDivisionError' in out
    assert f'{USER_CONTROLLERS / "user_controllers.py"}:' in out, out
    setpoints = _setpoints(run_dir)
    assert len(setpoints) >= 45 and setpoints[-1][0] < 1.0           # 0.5 s of its plan, then none
    assert all(math.isfinite(f) and all(map(math.isfinite, q)) for _, f, q in setpoints)
    log = (run_dir / 'logs' / 'node_host.log').read_text()   # the controller's process (with the simulator's)
    assert log.count('controller failed at t = ') == 1, log      # reported once, then silent


def test_fly_refuses_an_unusable_user_class_before_anything_starts(tmp_path, ros_env):
    for controller, says in (('user_controllers:MotorOnly', 'a motor-level controller cannot fly here'),
                             ('user_controllers:BrokenInit', "building user_controllers.BrokenInit failed: KeyError"),
                             ('no_such_package.mod:Class', "--controller 'no_such_package.mod:Class' refused: "
                                                           "importing 'no_such_package.mod' failed")):
        done, run_dir = _fly(tmp_path, ros_env, controller)
        assert done.returncode == 2 and says in done.stderr + done.stdout, done.stdout + done.stderr
        assert 'Traceback' not in done.stderr and not (run_dir / 'bag').exists()


def test_fly_flies_a_mission_whose_plan_is_a_user_trajectory_class(tmp_path, ros_env):
    """trajectory.generator: trajectory_node samples the class into `trajectory`, fly checks it against the vehicle
    first and the controller tracks it; the recorded plan is the class's circle."""
    path = tmp_path / 'circle.yaml'
    path.write_text(f'name: circle\nvehicle: {ROOT / "config/vehicles/crazyflie.yaml"}\n'
                    'waypoints: [[0, 0, 1], [1, 0, 1]]\n'     # the class starts at the first
                    'trajectory:\n  generator: quad_trajectory.templates.circle:Circle\n'
                    '  generator_args: {radius_m: 0.5, period_s: 6.0}\n')
    run_dir = tmp_path / 'run'
    done = subprocess.run([QUADFLIGHT, 'fly', str(path), '--out', str(run_dir)], env=ros_env, capture_output=True,
                          text=True, timeout=TIMEOUT_S)
    assert done.returncode == 0, done.stdout + done.stderr
    assert 'feasible on crazyflie' in done.stdout                  # the feasibility check ran on it
    metrics = json.loads((run_dir / 'metrics.json').read_text())
    assert metrics['completed'] and metrics['time_planned_s'] == 6.0 and metrics['rmse_m'] < 0.05   # the seed's pd
    assert abs(metrics['length_planned_m'] - 2 * math.pi * 0.5) < 0.01   # one lap of the class's circle
