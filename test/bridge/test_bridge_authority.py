"""Who may command the vehicle: the bridge flies setpoints only from its `setpoint_source` node. An
intruder node of the same ROS domain and namespace publishing a 10 deg roll on cmd/attitude_thrust is refused
and named in the diagnostics; `offboard` with only the intruder publishing is refused; with the controller
publishing too, every SET_ATTITUDE_TARGET the emulated PX4 receives (seen on the wire by a tap) is the
controller's level setpoint, none the intruder's."""

import math

import numpy as np
import pytest
from bridge_graph import SetpointPublisher, tapped_graph
from std_srvs.srv import SetBool

from quad_common import rotations

INTRUDER_ROLL_DEG = 10.0


@pytest.fixture
def graph(tmp_path):
    with tapped_graph(tmp_path) as g:
        yield g


def _roll_deg(msg):
    """Roll of a SET_ATTITUDE_TARGET's quaternion (w, x, y, z), NED/FRD: the same angle as in ENU/FLU."""
    w, x, y, z = msg.q
    return math.degrees(math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y)))


def test_an_intruders_setpoints_never_reach_the_vehicle(graph):
    procs, observer, start = graph
    tap = start('px4', extra=('--offboard-loss-s', '3.0'))
    intruder = SetpointPublisher(observer, node_name='intruder',
                                 quaternion=rotations.from_euler(math.radians(INTRUDER_ROLL_DEG), 0.0, 0.0))
    controller = None
    try:
        observer.wait_for(lambda: int(observer.setpoints()[1].get('refused_source', 0)) > 20,
                          "the intruder's setpoints refused")
        values = observer.setpoints()[1]
        assert 'intruder' in values['refused_publishers'] and values['received'] == '0', values
        assert values['setpoint_source'].endswith('/position_controller')
        answer = observer.call('offboard', SetBool.Request(data=True))
        assert not answer.success and 'intruder' in answer.message, answer.message
        assert tap.setpoints() == [], 'an intruder setpoint reached the vehicle'

        controller = SetpointPublisher(observer)   # the bridge's setpoint_source, level
        observer.wait_for(lambda: int(observer.setpoints()[1].get('received', 0)) > 20, "the controller's setpoints")
        answer = observer.call('offboard', SetBool.Request(data=True))
        assert answer.success, answer.message
        observer.wait_for(lambda: observer.link()[1].get('mode') == 'OFFBOARD', 'mode OFFBOARD')
        observer.wait_for(lambda: len(tap.setpoints()) > 200, '200 setpoints on the wire in OFFBOARD')
        assert intruder.count > 200   # it kept publishing all along
    finally:
        intruder.stop()
        if controller is not None:
            controller.stop()
    rolls = np.array([_roll_deg(m) for _, m in tap.setpoints()])
    assert np.abs(rolls).max() < 1.0, f'{np.sum(np.abs(rolls) > 1.0)} of {len(rolls)} setpoints not level'
    assert observer.link()[1].get('mode') == 'OFFBOARD'


def test_the_fast_dds_of_the_pypi_wheels_has_no_dds_security(tmp_path, ros_env):
    """docs/bridge.md says SROS2 cannot run on the wheels' Fast DDS (2.14, built without -DSECURITY=ON): an enclave
    under ROS_SECURITY_ENFORCE is refused by rmw_fastrtps. When this fails, the wheels gained the plugins: say so
    in docs/bridge.md ("Who can command your vehicle") and use SROS2."""
    import importlib.metadata
    import subprocess
    import sys
    try:
        importlib.metadata.distribution('ros-jazzy-rclpy')
    except importlib.metadata.PackageNotFoundError:
        pytest.skip('rclpy is not the PyPI wheels\' (a ROS install): its Fast DDS may carry DDS-Security')
    enclave = tmp_path / 'keystore' / 'enclaves' / 'probe'
    enclave.mkdir(parents=True)
    for name in ('identity_ca.cert.pem', 'cert.pem', 'key.pem', 'permissions_ca.cert.pem', 'governance.p7s',
                 'permissions.p7s'):
        (enclave / name).write_text('not a certificate\n')
    env = dict(ros_env, ROS_SECURITY_KEYSTORE=str(tmp_path / 'keystore'), ROS_SECURITY_ENABLE='true',
               ROS_SECURITY_STRATEGY='Enforce')
    out = subprocess.run([sys.executable, '-c', 'import rclpy; rclpy.init(args=["--ros-args", "--enclave", "/probe"]);'
                          ' rclpy.create_node("probe")'], env=env, capture_output=True, text=True, timeout=60)
    assert out.returncode != 0 and "doesn't have the security libraries" in out.stderr, out.stderr[-2000:]


def test_a_second_vehicle_on_the_link_is_refused_and_reported(tmp_path):
    """An emulator left running on the bridge's port, with the same system id (telemetry would mix:
    odometry jumping between the two) or another one (target_system 0 may have taken the wrong vehicle)."""
    from quad_bringup.emulated.vehicle_graph import free_udp_port, running_graph
    with running_graph(tmp_path) as (procs, observer):
        port = free_udp_port()
        procs.vehicle('px4', f'udpout:127.0.0.1:{port}')
        procs.bridge(f'udpin:127.0.0.1:{port}')
        observer.wait_for(lambda: observer.link()[1].get('armed') == 'True', 'the bridge to see the armed vehicle')
        assert observer.link()[1]['link_refusal'] == '' and observer.link()[1]['other_vehicles'] == ''

        procs.vehicle('px4', f'udpout:127.0.0.1:{port}', position=(0.0, -127.0, 0.0), name='stray')
        observer.wait_for(lambda: 'two vehicles send as system 1' in observer.link()[1].get('link_refusal', ''),
                          'the duplicate system 1 to be reported')
        answer = observer.call('arm', SetBool.Request(data=True))
        assert not answer.success and 'two vehicles send as system 1' in answer.message, answer.message
        procs.stop('stray')
        observer.wait_for(lambda: observer.link()[1].get('link_refusal') == '', 'the stray vehicle to be gone')

        procs.vehicle('px4', f'udpout:127.0.0.1:{port}', name='stray', extra=('--system-id', '2'))
        observer.wait_for(lambda: observer.link()[1].get('other_vehicles') == '2', 'vehicle 2 to be reported')
        assert 'set target_system' in observer.link()[1]['link_refusal']
        answer = observer.call('arm', SetBool.Request(data=True))
        assert not answer.success and 'set target_system' in answer.message, answer.message

        procs.stop('bridge')
        with observer.lock:
            observer.diagnostics.clear()
        procs.bridge(f'udpin:127.0.0.1:{port}', target_system=1)   # the operator names the vehicle to fly
        observer.wait_for(lambda: observer.link()[1].get('other_vehicles') == '2'
                          and observer.link()[1].get('armed') == 'True',   # vehicle 1's heartbeat heard too
                          'vehicle 2 reported again and vehicle 1 heard')
        assert observer.link()[1]['link_refusal'] == '' and observer.link()[1]['target_system'] == '1'
        answer = observer.call('arm', SetBool.Request(data=True))
        assert answer.success, answer.message


def test_quadflight_arm_offboard_land_call_the_bridge_without_the_ros2_cli(tmp_path):
    """The README's walk-through on a machine without ROS: `quadflight arm|offboard|land` (no ros2 CLI needed)."""
    import subprocess
    from pathlib import Path

    from quad_bringup.emulated.vehicle_graph import free_udp_port, running_graph
    quadflight = str(Path(__file__).resolve().parents[2] / 'quadflight')
    with running_graph(tmp_path) as (procs, observer):
        port = free_udp_port()
        procs.vehicle('px4', f'udpout:127.0.0.1:{port}', position=(0.0, 0.0, 0.0))
        procs.bridge(f'udpin:127.0.0.1:{port}')
        observer.wait_for(lambda: observer.link()[0] == 'link up', 'link up')
        ns = observer.node.get_namespace()

        def call(*args):
            return subprocess.run([quadflight, *args, '--namespace', ns, '--timeout-s', '60'], env=procs.env,
                                  capture_output=True, text=True, timeout=120)
        armed = call('arm')
        assert armed.returncode == 0 and 'accepted: arm: MAV_RESULT_ACCEPTED' in armed.stdout, armed.stderr
        refused = call('offboard')   # no controller publishing: refused, exit 1, the bridge's reason
        assert refused.returncode == 1 and 'no live setpoint stream' in refused.stderr, refused.stderr
        landed = call('land')
        assert landed.returncode == 0 and 'mode AUTO.LAND' in landed.stdout, landed.stderr
        nobody = subprocess.run([quadflight, 'land', '--namespace', '/nobody', '--timeout-s', '2'], env=procs.env,
                                capture_output=True, text=True, timeout=60)
        assert nobody.returncode == 2 and 'no mavlink_bridge offers /nobody/land' in nobody.stderr
