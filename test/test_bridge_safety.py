"""Bridge safety in a real graph: NaN and over-tilted setpoints are refused / clamped and counted; leaving the
geofence box lands the vehicle."""

import math
import subprocess
import sys

import pytest
import rclpy
from bridge_graph import free_udp_port, python_env, running_graph
from sensor_msgs.msg import Imu
from std_srvs.srv import SetBool

from quad_common import rotations
from quad_common.conversions import to_quaternion


@pytest.fixture
def graph(tmp_path):
    with running_graph(tmp_path) as g:
        yield g


def _setpoint(q, f):
    msg = Imu()
    msg.orientation = to_quaternion(q)
    msg.linear_acceleration.z = f
    msg.angular_velocity_covariance[0] = -1.0
    return msg


def test_bad_setpoints_are_counted_and_the_geofence_lands(graph):
    procs, observer = graph
    port = free_udp_port()
    procs.vehicle('px4', f'udpout:127.0.0.1:{port}', position=(0.0, 0.0, 1.0))
    procs.bridge(f'udpin:127.0.0.1:{port}', max_tilt_deg=30.0, geofence_enabled=True,
                 geofence_min_m='[-5.0, -5.0, -1.0]', geofence_max_m='[5.0, 5.0, 3.0]')
    observer.wait_for(lambda: observer.link()[1].get('armed') == 'True', 'the armed vehicle')
    controller = rclpy.create_node('position_controller', namespace=observer.node.get_namespace(),
                                   context=observer.context)   # the bridge's setpoint_source
    pub = controller.create_publisher(Imu, 'cmd/attitude_thrust', 10)

    def counts():
        entries = observer.diagnostics.get('mavlink_bridge: setpoints')
        return entries[-1][2] if entries else {}

    def publish_until(msg, key):
        observer.wait_for(lambda: pub.publish(msg) or int(counts().get(key, 0)) > 0, f'{key} setpoints counted')

    publish_until(_setpoint([0.0, 0.0, 0.0, 1.0], math.nan), 'refused')
    publish_until(_setpoint(rotations.from_euler(math.radians(60.0), 0.0, 0.0), 9.81), 'clamped')
    assert 'refused' in procs.log('bridge') and 'clamped to 30.0 deg' in procs.log('bridge')
    assert observer.link()[1]['mode'] == 'AUTO.LOITER'  # neither commanded anything

    procs.stop('bridge')
    procs.bridge(f'udpin:127.0.0.1:{port}', geofence_enabled=True, geofence_min_m='[-5.0, -5.0, -1.0]',
                 geofence_max_m='[5.0, 5.0, 0.5]')  # the vehicle hovers at 1 m: outside
    observer.wait_for(lambda: observer.link()[1].get('mode') == 'AUTO.LAND', 'the geofence to command AUTO.LAND')
    observer.wait_for(lambda: observer.link()[1].get('armed') == 'False', 'the vehicle to land and disarm')
    assert 'geofence: left the box' in procs.log('bridge')


@pytest.mark.parametrize('param, value', [('fcu_url', 'bogus:1'), ('autopilot', 'betaflight'),
                                          ('setpoint_rate_hz', '0.0'), ('geofence_min_m', '[1.0, 0.0, 0.0]')])
def test_bad_start_up_parameters_exit_2_naming_the_field(ros_env, param, value):
    env = python_env(ros_env)
    out = subprocess.run([sys.executable, '-m', 'quad_bridge.mavlink_bridge_node', '--ros-args',
                          '-p', f'{param}:={value}', '-p', 'geofence_max_m:=[1.0, 1.0, 1.0]'],
                         env=env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 2
    assert param in out.stderr + out.stdout


def test_signed_link(graph, tmp_path):
    """A vehicle that accepts only signed messages obeys a bridge with its key; a bridge without a key or with
    another key says it is signing (issue 27.3: they said "parameters not read" / "no vehicle heartbeat yet")."""
    procs, observer = graph
    key, wrong = tmp_path / 'signing.key', tmp_path / 'wrong.key'
    key.write_text('a5' * 32)
    wrong.write_text('5a' * 32)
    port = free_udp_port()
    procs.vehicle('px4', f'udpout:127.0.0.1:{port}', position=(0.0, 0.0, 0.0), extra=('--signing-key-file', str(key)))
    for key_file, says in (('', 'signing_key_file is empty'), (str(wrong), 'failed the MAVLink 2 signature check'),
                           (str(key), None)):
        with observer.lock:
            observer.diagnostics.clear()
        procs.bridge(f'udpin:127.0.0.1:{port}', command_timeout_s=1.0,
                     **({'signing_key_file': key_file} if key_file else {}))
        if says is None:
            observer.wait_for(lambda: observer.link()[0] == 'link up', 'the signed vehicle heard (signed bridge)')
            answer = observer.call('arm', SetBool.Request(data=True))
            assert answer.success, answer.message
            assert observer.link()[1]['signing'] == 'on'
        else:
            observer.wait_for(lambda says=says: says in observer.link()[1].get('signing', ''),
                              f'signing reported: {says}')
            answer = observer.call('arm', SetBool.Request(data=True))
            assert not answer.success and says in answer.message, answer.message
            procs.stop('bridge')
