"""A user's controller class flying an emulated PX4 through the bridge (trajectory-free hover in offboard): when it
fails mid-flight the setpoints stop, the bridge's stale-setpoint failsafe lands the vehicle, and the controller
names the class and the line; a motor-level class is refused before the graph flies."""

import subprocess
import sys

import pytest

from quad_bringup.emulated.vehicle_graph import free_udp_port, hover_in_offboard, python_env, running_graph
from quad_common import contract
from quad_common.paths import REPO_ROOT
from quad_common.ros.testing import isolated_domain

USER_CONTROLLERS = REPO_ROOT / 'src' / 'quad_control' / 'test'


@pytest.fixture
def graph(tmp_path):
    with running_graph(tmp_path) as g:
        yield g


def test_a_user_class_that_fails_in_offboard_lets_the_bridge_land_the_vehicle(graph, tmp_path):
    procs, observer = graph
    trigger = tmp_path / 'fail-now'
    procs.env = dict(procs.env, PYTHONPATH=f'{USER_CONTROLLERS}:{procs.env["PYTHONPATH"]}',
                     QUADFLIGHT_TEST_FAIL_FILE=str(trigger))
    # timeouts above a busy 2-core machine's stalls, as test_bridge_flight.py flies them
    hover_in_offboard(procs, observer, 'px4', free_udp_port(), bridge={'autopilot': 'auto', 'setpoint_timeout_s': 1.0},
                      controller={'controller': 'user_controllers:FailsOnFile', 'rate_hz': 50.0,
                                  'odom_timeout_s': 1.0})
    assert observer.controller()[1]['controller'] == 'user_controllers:FailsOnFile'
    trigger.touch()
    observer.wait_for(lambda: observer.link()[1].get('mode') == 'AUTO.LAND', 'the bridge to command AUTO.LAND')
    observer.wait_for(lambda: observer.link()[1].get('armed') == 'False', 'the vehicle to land and disarm')
    assert observer.position()[2] < 0.05
    assert int(observer.setpoints()[1]['stale_events']) >= 1
    log = procs.log('controller')
    assert log.count('controller failed at t = ') == 1, log
    assert 'user_controllers.FailsOnFile.update raised RuntimeError: my controller gave up' in log
    assert f'{USER_CONTROLLERS / "user_controllers.py"}:' in log
    assert procs.procs['controller'].poll() is None          # the node lives on, silent
    # and says so on every status after, not only on the fault's own: the periodic one is ERROR too
    seen = len(observer.diagnostics[contract.CONTROLLER_STATUS])
    observer.wait_for(lambda: len(observer.diagnostics[contract.CONTROLLER_STATUS]) > seen + 1, 'two more statuses')
    message, values = observer.controller()
    assert message.startswith('controller failed at t = ') and values['controller_failures'] == '1', message


def test_a_motor_level_class_is_refused_by_the_bridge_graph_s_controller():
    """The px4 launch graph's position_controller (wall clock, engagement) with a class giving motor speeds only:
    exit 2 with the reason before it publishes anything."""
    with isolated_domain() as (_, env):
        env = python_env(env)
        env['PYTHONPATH'] = f'{USER_CONTROLLERS}:{env["PYTHONPATH"]}'
        done = subprocess.run([sys.executable, '-m', 'quad_control.position_controller_node', '--ros-args',
                               '--params-file', str(REPO_ROOT / 'config' / 'control_real.yaml'),
                               '-p', 'controller:=user_controllers:MotorOnly', '-p', 'wait_for_engagement:=true'],
                              env=env, capture_output=True, text=True, timeout=120)
    out = done.stdout + done.stderr
    assert done.returncode == 2 and 'Traceback' not in out, out
    assert "cmd_motor_speeds, cmd_moment without cmd_thrust and cmd_q: a motor-level controller cannot fly here, " \
           "the attitude loop is the vehicle's (the autopilot's on a real one)" in out
