"""Bridge safety in a real graph: NaN and over-tilted setpoints are refused / clamped and counted; leaving the
geofence box lands the vehicle; flying towards it at 3 m/s, the vehicle brakes and stops inside it."""

import math
import subprocess
import sys

import pytest
import rclpy
from bridge_graph import SetpointPublisher
from sensor_msgs.msg import Imu
from std_srvs.srv import SetBool

from quad_bringup.emulated.vehicle_graph import free_udp_port, python_env, running_graph
from quad_common import rotations
from quad_common.conversions import to_quaternion
from quad_common.types import GRAVITY_MPS2


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
    another key says it is signing (they once said "parameters not read" / "no vehicle heartbeat yet")."""
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


FENCE_X_M = 6.0
SPEED_MPS = 3.0
SPEED_TILT_RAD = math.radians(15.0)


def _speed_mps(observer, span_s=0.1):
    """Horizontal speed over the newest odometry (stamps at least span_s apart), or 0."""
    with observer.lock:
        odom = observer.odom[-50:]
    if len(odom) < 2:
        return 0.0
    (t1, p1), older = odom[-1], [o for o in odom if o[0] <= odom[-1][0] - span_s]
    if not older:
        return 0.0
    t0, p0 = older[-1]
    return math.hypot(p1[0] - p0[0], p1[1] - p0[1]) / (t1 - t0)


def test_flying_at_the_geofence_at_3_mps_the_vehicle_brakes_and_stops_inside(graph):
    """Our setpoints fly the vehicle towards the box's +x wall (6 m) at 3 m/s and then keep it level: the bridge
    brakes where its stopping distance reaches the wall and lands it inside (reacting at the wall, PX4's hold
    stopped it 2.1 m past a 10 m fence and it landed 1.8 m outside)."""
    procs, observer = graph
    port = free_udp_port()
    procs.vehicle('px4', f'udpout:127.0.0.1:{port}', position=(0.0, 0.0, 2.0))
    procs.bridge(f'udpin:127.0.0.1:{port}', geofence_enabled=True, geofence_min_m='[-10.0, -5.0, -1.0]',
                 geofence_max_m=f'[{FENCE_X_M}, 5.0, 6.0]')
    observer.wait_for(lambda: observer.link()[1].get('armed') == 'True', 'the armed vehicle')
    level = (0.0, 0.0, 0.0, 1.0)
    publisher = SetpointPublisher(observer, quaternion=level, force_mps2=GRAVITY_MPS2)
    try:
        observer.wait_for(lambda: int(observer.setpoints()[1].get('received', 0)) > 20, 'setpoints at the bridge')
        answer = observer.call('offboard', SetBool.Request(data=True))
        assert answer.success, answer.message
        observer.wait_for(lambda: observer.link()[1].get('mode') == 'OFFBOARD', 'mode OFFBOARD')
        start = observer.position()
        publisher.quaternion = rotations.from_euler(0.0, SPEED_TILT_RAD, 0.0)   # body z towards +x
        publisher.force_mps2 = GRAVITY_MPS2 / math.cos(SPEED_TILT_RAD)
        observer.wait_for(lambda: _speed_mps(observer) >= SPEED_MPS - 0.3, f'{SPEED_MPS} m/s towards the wall')
        publisher.quaternion, publisher.force_mps2 = level, GRAVITY_MPS2    # coast level at that speed
        accelerated = observer.position()
        observer.wait_for(lambda: observer.link()[1].get('mode') == 'AUTO.LAND', 'the geofence to land the vehicle')
        observer.wait_for(lambda: observer.link()[1].get('armed') == 'False', 'the vehicle to land and disarm')
    finally:
        publisher.stop()
    with observer.lock:
        xs = [p[0] for _, p in observer.odom]
    assert max(xs) < FENCE_X_M, f'reached x = {max(xs):.2f} m past the wall at {FENCE_X_M} m'
    assert xs[-1] < FENCE_X_M, f'landed at x = {xs[-1]:.2f} m'
    log = procs.log('bridge')
    assert 'geofence ahead: braking' in log and 'geofence: stopped before the wall' in log, log[-2000:]
    braked_at = float(log.split('geofence ahead: braking at [')[1].split(',')[0])
    speed = float(log.split('geofence ahead: braking at [')[1].split('], ')[1].split(' m/s')[0])
    assert speed >= SPEED_MPS * 0.9 and accelerated[0] < braked_at, (start, accelerated, braked_at, speed)
    print(f'braking at x = {braked_at} m, {speed} m/s; farthest x = {max(xs):.2f} m, landed at {xs[-1]:.2f} m')
