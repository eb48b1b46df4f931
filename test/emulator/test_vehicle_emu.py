"""The emulator against a plain pymavlink ground station over real UDP/TCP (no quad_bridge): each test checks one
behaviour of docs/emulator.md's table, with the numbers PX4's and ArduPilot's source give."""

import math
import struct
import time

import numpy as np
import pytest
from vehicle_emu_client import PX4_MODES, level_q_wxyz

ATTITUDE, LOCAL_POSITION_NED, HIGHRES_IMU, SYS_STATUS = 30, 32, 105, 1
PREARM = 0x10000000
GUIDED, GUIDED_NOGPS, LOITER = 4, 20, 5


def _roll_deg(v, since):
    return [math.degrees(m.roll) for _, m in v.of_type('ATTITUDE', since)]


@pytest.mark.parametrize('mode', [GUIDED, GUIDED_NOGPS])
def test_ardupilot_flies_attitude_targets_in_guided_and_holds_the_last_for_guid_timeout(vehicles, mode):
    v = vehicles('ardupilot', '--param', 'GUID_TIMEOUT=1.5')
    assert v.set_interval(ATTITUDE, 50.0) == 0 and v.set_interval(LOCAL_POSITION_NED, 50.0) == 0
    assert v.command(176, 1, mode) == 0
    v.wait_for(lambda: v.mode() == mode, f'mode {mode}')
    z0 = v.wait_message('LOCAL_POSITION_NED', time.monotonic()).z
    v.start_stream(20.0, level_q_wxyz(math.radians(10.0)), 0.5)
    v.wait_for(lambda: (_roll_deg(v, time.monotonic() - 0.1) or [0])[-1] > 9.0, 'roll 10 deg in', 10.0)
    stopped = v.stop_stream()
    v.wait_for(lambda: time.monotonic() > stopped + 1.0, '1 s after the last target')
    held = _roll_deg(v, stopped + 0.2)
    assert min(held) > 8.0, 'the last target is held for GUID_TIMEOUT'
    v.wait_for(lambda: time.monotonic() > stopped + 3.0, 'past GUID_TIMEOUT')
    leveled = _roll_deg(v, stopped + 2.5)
    assert max(abs(r) for r in leveled) < 2.0, 'levels after GUID_TIMEOUT'
    assert v.mode() == mode, 'and stays in its guided mode'
    last = v.last('LOCAL_POSITION_NED')
    assert abs(last.y) > 0.3, 'it drifted east while rolled (no position hold)'
    assert abs(last.z - z0) < 0.2, 'thrust 0.5 with GUID_OPTIONS 0 is climb rate 0: altitude held'


def test_ardupilot_ignores_attitude_targets_outside_guided(vehicles):
    v = vehicles('ardupilot')
    v.set_interval(ATTITUDE, 50.0)
    assert v.mode() == LOITER
    since = time.monotonic()
    v.start_stream(20.0, level_q_wxyz(math.radians(10.0)), 0.5)
    v.wait_for(lambda: time.monotonic() > since + 1.5, '1.5 s of targets in LOITER')
    assert max(abs(r) for r in _roll_deg(v, since)) < 2.0


def test_ardupilot_thrust_field_follows_guid_options(vehicles):
    v = vehicles('ardupilot', '--hover-throttle', '0.4')
    v.set_interval(LOCAL_POSITION_NED, 50.0)
    assert v.param('MOT_THST_HOVER').param_value == pytest.approx(0.4)
    assert v.command(176, 1, GUIDED_NOGPS) == 0
    v.start_stream(20.0, level_q_wxyz(), 0.4)     # GUID_OPTIONS 0: 0.4 -> descend at 0.2 * WPNAV_SPEED_DN
    t = time.monotonic()
    v.wait_for(lambda: time.monotonic() > t + 2.0, '2 s of climb-rate commands')
    vz = np.median([m.vz for _, m in v.of_type('LOCAL_POSITION_NED', t + 1.0)])
    assert vz == pytest.approx(0.2 * 1.5, abs=0.08)   # NED: + is down
    assert v.param('GUID_OPTIONS', 8.0, 6).param_value == 8.0
    t = time.monotonic()                               # now thrust: 0.4 = MOT_THST_HOVER hovers
    v.wait_for(lambda: time.monotonic() > t + 2.0, '2 s of thrust commands')
    vz = np.median([m.vz for _, m in v.of_type('LOCAL_POSITION_NED', t + 1.0)])
    assert abs(vz) < 0.08


def test_ardupilot_streams_only_what_is_asked_and_has_no_highres_imu(vehicles):
    v = vehicles('ardupilot', tcp=True)
    t = time.monotonic()
    v.wait_for(lambda: time.monotonic() > t + 2.0, '2 s of silence')
    with v.lock:
        kinds = {m.get_type() for _, m in v.messages}
    assert kinds <= {'HEARTBEAT', 'STATUSTEXT'}, kinds
    since = time.monotonic()
    assert v.set_interval(HIGHRES_IMU, 50.0) == 4                      # MAV_RESULT_FAILED
    v.wait_message('STATUSTEXT', since, lambda m: 'No ap_message for mavlink id (105)' in m.text)
    since = time.monotonic()
    v.send('request_data_stream', 1, 1, 10, 10, 1)                      # EXTRA1 at 10 Hz: ATTITUDE
    v.send('request_data_stream', 1, 1, 2, 2, 1)                        # EXTENDED_STATUS: SYS_STATUS
    v.wait_for(lambda: len(v.of_type('ATTITUDE', since)) > 20, 'ATTITUDE from REQUEST_DATA_STREAM')
    arrivals = [t for t, _ in v.of_type('ATTITUDE', since + 0.5)]
    rate = (len(arrivals) - 1) / (arrivals[-1] - arrivals[0])
    assert 7.0 < rate < 13.0
    assert not v.of_type('HIGHRES_IMU', 0) and not v.of_type('ODOMETRY', 0)
    status = v.wait_message('SYS_STATUS', since)                        # GCS.cpp: present, enabled, health
    assert status.onboard_control_sensors_present & PREARM
    assert status.onboard_control_sensors_enabled & PREARM
    assert status.onboard_control_sensors_health & PREARM


def test_ardupilot_parameters_timesync_and_boot_clock(vehicles):
    v = vehicles('ardupilot', '--hover-throttle', '0.45')
    since = time.monotonic()
    v.send('param_request_list', 1, 1)
    v.wait_for(lambda: len(v.of_type('PARAM_VALUE', since)) >= 9, 'the parameter list')
    values = {m.param_id: m for _, m in v.of_type('PARAM_VALUE', since)}
    expected = {'GUID_OPTIONS': (0.0, 6), 'GUID_TIMEOUT': (3.0, 9), 'MOT_THST_HOVER': (0.45, 9),
                'ATC_ANGLE_BOOST': (1.0, 2)}
    for name, (value, mav_type) in expected.items():
        assert values[name].param_value == pytest.approx(value, abs=1e-6) and values[name].param_type == mav_type
    assert v.param('GUID_TIMEOUT', 2.0).param_value == pytest.approx(2.0)
    assert v.param('GUID_TIMEOUT', 99.0).param_value == pytest.approx(2.0)   # out of range: refused
    v.set_interval(ATTITUDE, 20.0)
    since = time.monotonic()
    v.send('timesync', 0, 777)
    answer = v.wait_message('TIMESYNC', since, lambda m: m.ts1 == 777)
    attitude = v.wait_message('ATTITUDE', since)
    # one clock: TIMESYNC's tc1 (ns) and the telemetry's time_boot_ms agree within the latency and the loop
    assert abs(answer.tc1 / 1e6 - attitude.time_boot_ms) < 200.0
    assert attitude.time_boot_ms > 37000, 'the vehicle booted before the ground station connected'


def test_px4_offboard_needs_a_setpoint_stream_first_and_fails_safe_as_px4_does(vehicles):
    """Without RC the default COM_OBL_RC_ACT 0 (Position) is POSCTL all the same (PX4's failsafe framework leaves
    manual control out of modeCanRun), flown without sticks as PX4 v1.16 SIH flew it with the bridge killed:
    descending level at about MPC_LAND_SPEED (0.7 m/s), nothing holding it horizontally."""
    v = vehicles('px4', position=(0.0, 0.0, 5.0))
    v.set_interval(0, 20.0)                                             # HEARTBEAT at 20 Hz: timing
    assert v.mode() == PX4_MODES['AUTO.LOITER']
    assert v.set_mode(6) != 0, 'OFFBOARD without a setpoint stream is refused'
    started = time.monotonic()
    v.start_stream(1.0, level_q_wxyz(), 0.5)
    v.wait_for(lambda: time.monotonic() > started + 2.5, 'a 1 Hz stream for 2.5 s')
    assert v.set_mode(6) != 0, 'a 1 Hz stream is below the > 2 Hz PX4 asks for'
    v.start_stream(20.0, level_q_wxyz(), 0.5)
    v.wait_for(lambda: v.set_mode(6) == 0, 'OFFBOARD accepted with a 20 Hz stream', 10.0)
    v.wait_for(lambda: v.mode() == PX4_MODES['OFFBOARD'], 'OFFBOARD')
    stopped = v.stop_stream()
    changed = v.wait_for(lambda: next((t for t, m in v.of_type('HEARTBEAT', stopped)
                                       if m.custom_mode != PX4_MODES['OFFBOARD']), None), 'the failsafe')
    assert v.mode() == PX4_MODES['POSCTL'], 'COM_OBL_RC_ACT 0 without RC: POSCTL'
    assert 0.9 < changed - stopped < 3.0, 'after COM_OF_LOSS_T = 1 s (a busy machine adds up to ~1 s)'
    later = v.wait_for(lambda: next((t for t, m in v.of_type('LOCAL_POSITION_NED', changed) if t > changed + 1.5),
                                    None), '1.5 s of the failsafe')
    vz = v.wait_message('LOCAL_POSITION_NED', later).vz
    assert 0.5 < vz < 0.9, f'descending at MPC_LAND_SPEED (NED vz {vz:.2f} m/s)'


def test_px4_returns_to_offboard_after_land_and_arms_into_the_stream(vehicles):
    v = vehicles('px4', '--param', 'COM_DISARM_LAND=0.5')
    v.set_interval(0, 20.0)
    v.start_stream(20.0, level_q_wxyz(), 0.5)
    v.wait_for(lambda: v.set_mode(6) == 0, 'OFFBOARD', 10.0)
    assert v.command(21) == 0                                            # MAV_CMD_NAV_LAND
    v.wait_for(lambda: v.mode() == PX4_MODES['AUTO.LAND'], 'AUTO.LAND')
    v.wait_for(lambda: not v.armed(), 'landed and disarmed', 30.0)
    v.wait_for(lambda: v.mode() == PX4_MODES['OFFBOARD'], 'back to the user-intended OFFBOARD after disarm')
    z_ground = v.last('LOCAL_POSITION_NED').z
    v.start_stream(20.0, level_q_wxyz(), 0.6)                           # above hover
    assert v.command(400, 1) == 0, 'arming in OFFBOARD with a live stream is accepted'
    v.wait_for(lambda: v.last('LOCAL_POSITION_NED').z < z_ground - 0.5, 'the vehicle to fly the stream', 10.0)


def test_px4_sys_status_sets_only_the_prearm_health_bit_and_default_streams(vehicles):
    v = vehicles('px4', '--hover-throttle', '0.42')
    since = time.monotonic()
    status = v.wait_message('SYS_STATUS', since)
    assert not status.onboard_control_sensors_present & PREARM
    assert not status.onboard_control_sensors_enabled & PREARM
    assert status.onboard_control_sensors_health & PREARM               # AUTO.LOITER can arm
    for kind in ('HIGHRES_IMU', 'ODOMETRY', 'ATTITUDE_QUATERNION', 'LOCAL_POSITION_NED'):
        v.wait_message(kind, since)                                      # onboard-mode defaults, unasked
    odom, pos = v.last('ODOMETRY'), v.last('LOCAL_POSITION_NED')
    assert (odom.frame_id, odom.child_frame_id) == (1, 1)                # LOCAL_NED pose, NED velocity (EKF2)
    assert odom.z == pytest.approx(pos.z, abs=0.05) and odom.z == pytest.approx(-1.0, abs=0.1)
    assert v.param('MPC_THR_HOVER').param_value == pytest.approx(0.42)
    assert v.param('COM_OF_LOSS_T').param_value == pytest.approx(1.0)
    action = v.param('COM_OBL_RC_ACT')
    assert action.param_type == 6 and action.param_value == 0.0        # int 0, bytewise
    v.wait_message('TIMESYNC', since, lambda m: m.tc1 == 0)             # PX4 asks for our time
    assert v.set_mode(4, 6) == 0                                         # AUTO.LAND: cannot arm there
    since = time.monotonic()
    status = v.wait_message('SYS_STATUS', since + 0.1)
    assert not status.onboard_control_sensors_health & PREARM


def test_ardupilot_telemetry_leaves_in_bursts_stamped_with_its_sample_time(vehicles):
    v = vehicles('ardupilot')
    v.set_interval(ATTITUDE, 50.0)
    v.set_interval(LOCAL_POSITION_NED, 50.0)
    since = time.monotonic() + 0.5
    v.wait_for(lambda: len(v.of_type('LOCAL_POSITION_NED', since)) > 100, '2 s of 50 Hz telemetry')
    arrivals = np.sort([t for kind in ('ATTITUDE', 'LOCAL_POSITION_NED') for t, _ in v.of_type(kind, since)])
    gaps = np.diff(arrivals)
    assert np.mean(gaps < 0.002) > 0.5, 'most messages leave together with others (buckets, bursts)'
    assert gaps.max() > 0.03, 'with pauses between bursts'
    stamps = np.diff([m.time_boot_ms for _, m in v.of_type('LOCAL_POSITION_NED', since)])
    assert np.median(stamps) == pytest.approx(20.0, abs=3.0), 'the time field keeps the 20 ms sample spacing'


def test_ardupilot_stays_in_land_after_landing_and_refuses_to_arm_there(vehicles):
    v = vehicles('ardupilot', '--param', 'LAND_SPEED=100')
    assert v.command(21) == 0                                            # MAV_CMD_NAV_LAND
    v.wait_for(lambda: not v.armed(), 'landed and disarmed', 30.0)
    assert v.mode() == 9, 'ArduCopter stays in LAND (no return to a user mode, unlike PX4)'
    assert v.command(400, 1) == 4, 'LAND does not allow arming: MAV_RESULT_FAILED'


def test_px4_offboard_loss_action_is_a_parameter_sent_bytewise(vehicles):
    v = vehicles('px4')
    v.set_interval(0, 20.0)
    land = struct.unpack('<f', struct.pack('<i', 4))[0]                 # COM_OBL_RC_ACT 4 = Land, int32 bytewise
    assert v.param('COM_OBL_RC_ACT', land, 6).param_value == land
    v.start_stream(20.0, level_q_wxyz(), 0.5)
    v.wait_for(lambda: v.set_mode(6) == 0, 'OFFBOARD', 10.0)
    v.stop_stream()
    v.wait_for(lambda: v.mode() == PX4_MODES['AUTO.LAND'], 'the offboard-loss failsafe to land')
