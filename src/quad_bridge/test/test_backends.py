"""The PX4 and ArduPilot backends: mode encodings, thrust semantics, arming rules, pre-arm bits and the check of
the vehicle's semantic parameters (values from PX4's / ArduPilot's sources, named in quad_bridge.px4/ardupilot)."""

import math
import struct

import pytest

from quad_bridge import ardupilot, px4
from quad_bridge.backend import MAV_SYS_STATUS_PREARM_CHECK as PREARM
from quad_bridge.backend import BridgeConfig
from quad_bridge.backends import BACKENDS, backend_for, resolve
from quad_common import rotations
from quad_common.types import AttitudeSetpoint

PX4, APM = px4.Px4(), ardupilot.ArduPilot()
G = 9.81


def test_backend_for_picks_by_heartbeat_autopilot_and_names_the_unknown():
    assert backend_for(12).name == 'PX4' and backend_for(3).name == 'ArduPilot'
    with pytest.raises(ValueError, match='autopilot 8 has no backend'):
        backend_for(8)
    assert resolve('auto', 12).name == 'PX4' and resolve('auto', 3).name == 'ArduPilot'
    assert resolve('px4', 3).name == 'PX4' and set(BACKENDS) == {'px4', 'ardupilot'}
    with pytest.raises(ValueError, match='autopilot = auto: autopilot 8 has no backend.*px4, ardupilot'):
        resolve('auto', 8)


def test_px4_custom_mode_packs_main_in_bits_16_23_and_sub_in_24_31():
    assert px4.custom_mode(6) == 0x00060000 == 393216              # OFFBOARD
    assert PX4.custom_mode('AUTO.LAND') == 0x06040000 == 100925440
    assert px4.decode(0x03040000) == (4, 3)                        # AUTO.LOITER
    assert PX4.mode_name(0x06040000) == 'AUTO.LAND' and PX4.mode_name(0x00030000) == 'POSCTL'
    assert PX4.mode_params('OFFBOARD') == (6, 0) and PX4.mode_params('AUTO.LAND') == (4, 6)
    assert PX4.mode_name(px4.custom_mode(9)) == 'MAIN_9'


def test_ardupilot_mode_numbers():
    assert (APM.mode_name(4), APM.mode_name(9), APM.mode_name(20)) == ('GUIDED', 'LAND', 'GUIDED_NOGPS')
    assert APM.mode_params('GUIDED_NOGPS') == (20, 0) and APM.custom_mode('LAND') == 9


def test_unknown_mode_names_are_refused_by_name():
    for backend, name in ((PX4, 'FLYING'), (PX4, 'AUTO.NOPE'), (APM, 'OFFBOARD')):
        with pytest.raises(ValueError, match=name):
            backend.mode_params(name)


def test_which_modes_obey_attitude_targets():
    assert PX4.obeys_setpoints('OFFBOARD') and not PX4.obeys_setpoints('AUTO.LOITER')
    assert APM.obeys_setpoints('GUIDED') and APM.obeys_setpoints('GUIDED_NOGPS')   # GUIDED_NOGPS is a guided mode
    assert not APM.obeys_setpoints('LOITER') and not APM.obeys_setpoints('LAND')
    assert PX4.prestream and not APM.prestream
    assert PX4.hold_mode('hold') == 'AUTO.LOITER' and PX4.hold_mode('land') == 'AUTO.LAND'
    assert APM.hold_mode('hold') == 'LAND'


def test_px4_refuses_arming_in_offboard_without_a_hand_over():
    assert 'returns to OFFBOARD' in PX4.arm_refusal('OFFBOARD', handing_over=False)
    assert PX4.arm_refusal('OFFBOARD', handing_over=True) is None
    assert PX4.arm_refusal('POSCTL', handing_over=False) is None
    assert APM.arm_refusal('GUIDED', handing_over=False) is None   # GUIDED takeoff is the normal way


def test_prearm_bits_as_each_autopilot_sets_them():
    assert PX4.prearm_ready(0, 0, PREARM) is True                   # PX4 sets the health bit only
    assert PX4.prearm_ready(PREARM, PREARM, 0) is False
    assert APM.prearm_ready(PREARM, PREARM, PREARM) is True
    assert APM.prearm_ready(PREARM, PREARM, 0) is False
    assert APM.prearm_ready(PREARM, 0, 0) is None                   # ARMING_CHECK = 0: no verdict


def test_px4_thrust_is_hover_throttle_at_g_and_clipped():
    cfg = BridgeConfig(hover_throttle=0.45)
    assert PX4.thrust(AttitudeSetpoint(specific_force_mps2=G), cfg) == pytest.approx(0.45)
    assert PX4.thrust(AttitudeSetpoint(specific_force_mps2=100.0), cfg) == 1.0
    assert PX4.specific_force(0.45, cfg, None) == pytest.approx(G)


def test_ardupilot_thrust_is_not_boosted_twice_and_follows_angle_boost():
    q = rotations.from_euler(math.radians(30.0), 0.0, 0.0)
    f = G / math.cos(math.radians(30.0))       # level flight at 30 deg bank
    cfg = BridgeConfig(hover_throttle=0.5)
    thrust = APM.thrust(AttitudeSetpoint(quaternion=q, specific_force_mps2=f), cfg)
    assert thrust == pytest.approx(0.5)        # the vehicle boosts 0.5 by 1/cos(30) itself
    assert APM.specific_force(thrust, cfg, q) == pytest.approx(f)
    no_boost = BridgeConfig(hover_throttle=0.5, angle_boost=False)
    assert APM.thrust(AttitudeSetpoint(quaternion=q, specific_force_mps2=f), no_boost) == pytest.approx(0.5 * f / G)


def test_ardupilot_climb_rate_semantics():
    assert ardupilot.climb_rate_to_thrust(0.0, 2.5, 1.5) == 0.5
    assert ardupilot.climb_rate_to_thrust(2.5, 2.5, 1.5) == 1.0
    assert ardupilot.climb_rate_to_thrust(-1.5, 2.5, 1.5) == 0.0
    for rate in (-1.5, -0.3, 0.0, 0.7, 2.5):
        assert ardupilot.thrust_to_climb_rate(ardupilot.climb_rate_to_thrust(rate, 2.5, 1.5), 2.5, 1.5) == \
            pytest.approx(rate)
    cfg = BridgeConfig(ardupilot_thrust_mode='climb_rate', climb_rate_lead_s=0.5)
    level = AttitudeSetpoint(quaternion=rotations.from_yaw(0.3), specific_force_mps2=G + 1.0)
    assert APM.thrust(level, cfg, vertical_velocity_mps=0.0) == pytest.approx(0.5 + 0.5 * 0.5 / 2.5)


def _apm_params(options=8, hover=0.5, boost=1):
    return {'GUID_OPTIONS': options, 'MOT_THST_HOVER': hover, 'ATC_ANGLE_BOOST': boost}


def test_ardupilot_guid_options_bit_3_must_match_the_thrust_mode():
    cfg = BridgeConfig(hover_throttle=0.5, ardupilot_thrust_mode='thrust')
    assert APM.check_params(_apm_params(8), cfg, 'check').problems == ()
    problems = APM.check_params(_apm_params(0), cfg, 'check').problems
    assert len(problems) == 1 and 'GUID_OPTIONS = 0' in problems[0] and 'climb rate' in problems[0]
    adopted = APM.check_params(_apm_params(0), cfg, 'adopt')
    assert adopted.problems == () and adopted.config.ardupilot_thrust_mode == 'climb_rate'
    climb = BridgeConfig(ardupilot_thrust_mode='climb_rate')
    assert 'GUID_OPTIONS = 8' in APM.check_params(_apm_params(8), climb, 'check').problems[0]


def test_hover_thrust_mismatch_beyond_the_tolerance_is_refused():
    cfg = BridgeConfig(hover_throttle=0.5, hover_throttle_tolerance=0.03)
    assert APM.check_params(_apm_params(hover=0.52), cfg, 'check').problems == ()
    problem = APM.check_params(_apm_params(hover=0.367), cfg, 'check').problems[0]
    assert 'MOT_THST_HOVER = 0.367' in problem and 'hover_throttle = 0.500' in problem
    assert APM.check_params(_apm_params(hover=0.367), cfg, 'adopt').config.hover_throttle == pytest.approx(0.367)
    px = PX4.check_params({'MPC_THR_HOVER': 0.39, 'COM_OF_LOSS_T': 1.0}, cfg, 'check')
    assert 'MPC_THR_HOVER = 0.390' in px.problems[0]


def test_angle_boost_off_is_taken_into_the_thrust_encoding():
    check = APM.check_params(_apm_params(boost=0), BridgeConfig(), 'check')
    assert check.problems == () and check.config.angle_boost is False and 'ATC_ANGLE_BOOST = 0' in check.notes[0]


def test_px4_offboard_loss_time_against_the_keep_alive():
    cfg = BridgeConfig(hover_throttle=0.5, setpoint_rate_hz=2.0, setpoint_timeout_s=0.5)
    assert 'COM_OF_LOSS_T = 0.40' in PX4.check_params({'MPC_THR_HOVER': 0.5, 'COM_OF_LOSS_T': 0.4}, cfg,
                                                      'check').problems[0]
    # the wire's longest gap is 1.5 periods (the keep-alive's first re-send): 0.75 s at 2 Hz
    assert 'longest gap 0.75 s' in PX4.check_params({'MPC_THR_HOVER': 0.5, 'COM_OF_LOSS_T': 0.7}, cfg,
                                                    'check').problems[0]
    assert PX4.check_params({'MPC_THR_HOVER': 0.5, 'COM_OF_LOSS_T': 0.8}, cfg, 'check').problems == ()
    ok = PX4.check_params({'MPC_THR_HOVER': 0.5, 'COM_OF_LOSS_T': 0.3}, BridgeConfig(setpoint_timeout_s=0.5), 'check')
    assert ok.problems == () and 'acts before' in ok.notes[0]


def test_unread_parameters_refuse_unless_ignored():
    check = PX4.check_params({'MPC_THR_HOVER': 0.5}, BridgeConfig(), 'check')
    assert 'COM_OF_LOSS_T not read' in check.problems[0]
    assert PX4.check_params({}, BridgeConfig(), 'ignore').problems == ()


def test_px4_integer_parameters_are_bytewise():
    as_float = struct.unpack('<f', struct.pack('<i', 8))[0]
    assert PX4.decode_param(as_float, 6) == 8.0        # MAV_PARAM_TYPE_INT32
    assert PX4.decode_param(0.39, 9) == pytest.approx(0.39)
    assert APM.decode_param(8.0, 6) == 8.0             # ArduPilot casts to float
