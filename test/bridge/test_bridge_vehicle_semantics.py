"""What the bridge reads from the vehicle before it hands over, and which telemetry it uses, against the emulator of the
autopilots' behaviour over real UDP: contradicting parameters refuse `offboard` with the parameter's name;
ArduPilot's IMU comes from SCALED_IMU (it has no HIGHRES_IMU); one odometry source although PX4 sends
LOCAL_POSITION_NED and ODOMETRY; PX4's pre-arm verdict from the health bit alone."""

import threading

import numpy as np
import pytest
from bridge_graph import SetpointPublisher, tapped_graph
from pymavlink.dialects.v20 import common as mavlink
from sensor_msgs.msg import Imu
from std_srvs.srv import SetBool


@pytest.fixture
def graph(tmp_path):
    with tapped_graph(tmp_path) as (procs, observer, start):
        yield procs, observer, lambda flavour, extra=(), **bridge_params: start(flavour, extra=extra, **bridge_params)


def _offboard_with_setpoints(observer, tap):
    publisher = SetpointPublisher(observer)
    try:
        observer.wait_for(lambda: int(observer.setpoints()[1].get('received', 0)) > 10 or tap.setpoints(),
                          'the bridge to hear the setpoints')
        return observer.call('offboard', SetBool.Request(data=True))
    finally:
        publisher.stop()


def test_ardupilot_guid_options_contradiction_refuses_offboard(graph):
    """GUID_OPTIONS 0 (ArduPilot's default): the thrust field is a climb rate; the bridge is set for thrust."""
    procs, observer, start = graph
    tap = start('ardupilot', ardupilot_thrust_mode='thrust')
    result = _offboard_with_setpoints(observer, tap)
    assert not result.success
    assert 'GUID_OPTIONS = 0' in result.message and 'climb rate' in result.message
    assert observer.link()[1]['mode'] != 'GUIDED_NOGPS' and tap.setpoints() == []
    observer.wait_for(lambda: 'GUID_OPTIONS = 0' in observer.link()[1].get('param_problems', ''),
                      'diagnostics to name the contradiction')


def test_hover_thrust_mismatch_refuses_offboard(graph):
    procs, observer, start = graph
    tap = start('px4', extra=('--hover-throttle', '0.4'), hover_throttle=0.5)
    result = _offboard_with_setpoints(observer, tap)
    assert not result.success and 'MPC_THR_HOVER = 0.400' in result.message, result.message
    assert observer.link()[1]['mode'] != 'OFFBOARD'


def test_adopted_hover_thrust_is_flown(graph):
    procs, observer, start = graph
    tap = start('px4', extra=('--hover-throttle', '0.4', '--offboard-loss-s', '3.0'), hover_throttle=0.5,
                vehicle_params='adopt')
    result = _offboard_with_setpoints(observer, tap)
    assert result.success, result.message
    assert abs(tap.setpoints()[-1][1].thrust - 0.4) < 1e-3          # f = g at the vehicle's hover thrust


def test_ardupilot_imu_comes_from_scaled_imu(graph):
    """ArduCopter has no HIGHRES_IMU: `imu` must still be published (point 6)."""
    procs, observer, start = graph
    imus, lock = [], threading.Lock()

    def on_imu(msg):
        with lock:
            imus.append((msg.linear_acceleration.z, msg.angular_velocity.z))
    observer.node.create_subscription(Imu, 'imu', on_imu, 10)
    start('ardupilot', extra=('--param', 'GUID_OPTIONS=8'))
    observer.wait_for(lambda: len(imus) > 20, '20 imu messages')
    with lock:
        f_z = np.median([a for a, _ in imus])
    assert f_z == pytest.approx(9.81, abs=0.5)                     # hovering: the accelerometer reads +g (FLU)
    values = observer.link()[1]
    assert values['imu_source'] == 'SCALED_IMU' and 'HIGHRES_IMU' not in values['missing_streams']


def test_px4_one_odometry_source_and_its_prearm_verdict(graph):
    """PX4's onboard link sends LOCAL_POSITION_NED and ODOMETRY unasked: odom comes from one only, named
    (point 5); PX4 sets only the health bit of the pre-arm check (point 7)."""
    procs, observer, start = graph
    tap = start('px4')
    observer.wait_for(lambda: tap.from_vehicle['ODOMETRY'] > 10, 'PX4 to send ODOMETRY too')
    def counts():
        with observer.lock, tap.lock:
            return len(observer.odom), tap.from_vehicle['LOCAL_POSITION_NED'], tap.from_vehicle['ODOMETRY']
    n_odom, n_lpn, n_odometry = counts()
    observer.wait_for(lambda: counts()[0] - n_odom > 100, '100 odom messages')
    odom, lpn, odometry = (now - before for now, before in zip(counts(), (n_odom, n_lpn, n_odometry)))
    # each odom comes from one earlier LOCAL_POSITION_NED (a few may be in flight when counting starts)
    assert odometry > 30 and odom <= lpn + 5, f'{odom} odom from {lpn} LOCAL_POSITION_NED + {odometry} ODOMETRY'
    values = observer.link()[1]
    assert values['odometry_source'] == 'LOCAL_POSITION_NED+ATTITUDE_QUATERNION'
    observer.wait_for(lambda: observer.link()[1].get('prearm_ready') == 'True', 'prearm_ready from the health bit')


def test_hover_thrust_changed_on_the_vehicle_after_connect_is_read_again_at_offboard(graph):
    """Agreeing at connect (0.5 both), then a ground station sets MPC_THR_HOVER 0.4 on the vehicle: `offboard`
    reads the parameters again and refuses naming the vehicle's new value (flying on connect's
    check would be 20 % of thrust off)."""
    procs, observer, start = graph
    tap = start('px4', hover_throttle=0.5)
    observer.wait_for(lambda: observer.link()[1].get('vehicle_params', '').startswith('COM_OF_LOSS_T'),
                      'the bridge to read the parameters on connect')
    assert observer.link()[1]['param_problems'] == ''
    with tap.lock:
        answered = tap.from_vehicle['PARAM_VALUE']
    tap.send_as_gcs(mavlink.MAVLink_param_set_message(1, 1, b'MPC_THR_HOVER', 0.4, mavlink.MAV_PARAM_TYPE_REAL32))

    def vehicle_answered():
        with tap.lock:
            return tap.from_vehicle['PARAM_VALUE'] > answered
    observer.wait_for(vehicle_answered, 'the vehicle to answer the PARAM_SET')
    result = _offboard_with_setpoints(observer, tap)
    assert not result.success and 'MPC_THR_HOVER = 0.400' in result.message, result.message
    assert observer.link()[1]['mode'] != 'OFFBOARD' and tap.setpoints() == []
