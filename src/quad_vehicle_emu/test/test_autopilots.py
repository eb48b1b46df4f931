"""The autopilot cores without sockets: type_mask rules that the graph tests do not reach."""

import math

import numpy as np
import pytest

from quad_common.types import GRAVITY_MPS2, State
from quad_vehicle_emu import protocol as p
from quad_vehicle_emu.autopilots import ArduCopter, AttitudeTargetMsg, Px4

LEVEL = (1.0, 0.0, 0.0, 0.0)
HOVERING = State(position=np.array([0.0, 0.0, 1.0]))


def _offboard_px4(msg):
    px4 = Px4(hover_throttle=0.5)
    px4.armed = True
    for k in range(30):
        px4.on_attitude_target(msg, k * 0.02)
    assert px4.command(p.MAV_CMD_DO_SET_MODE, [1, 6, 0], False, 0.6) == p.MAV_RESULT_ACCEPTED
    return px4.update(HOVERING, False, 0.6)


def test_px4_thrust_body_set_uses_thrust_body_z():
    sp = _offboard_px4(AttitudeTargetMsg(p.TYPEMASK_RATES_IGNORE | p.TYPEMASK_THRUST_BODY_SET, LEVEL, (0, 0, 0),
                                         0.9, (0.0, 0.0, -0.5)))
    assert sp.specific_force_mps2 == pytest.approx(GRAVITY_MPS2)     # 0.5 = hover, not the 0.9 in thrust
    sp = _offboard_px4(AttitudeTargetMsg(p.TYPEMASK_RATES_IGNORE, LEVEL, (0, 0, 0), 0.6))
    assert sp.specific_force_mps2 == pytest.approx(0.6 * GRAVITY_MPS2 / 0.5)


@pytest.mark.parametrize('mask, q', [(p.TYPEMASK_THROTTLE_IGNORE | 7, LEVEL), (7, (1.01, 0.0, 0.0, 0.0)),
                                     (p.TYPEMASK_BODY_ROLL_RATE_IGNORE, LEVEL)])
def test_arducopter_resets_the_guided_target_on_an_ill_defined_message(mask, q):
    apm = ArduCopter(hover_throttle=0.5)
    apm.armed = True
    apm.command(p.MAV_CMD_DO_SET_MODE, [1, 20, 0], False, 0.0)
    tilted = (math.cos(0.1), math.sin(0.1), 0.0, 0.0)
    apm.on_attitude_target(AttitudeTargetMsg(7, tilted, (0, 0, 0), 0.5), 0.1)
    assert apm.angle[0] is not None
    with pytest.raises(ValueError):
        apm.on_attitude_target(AttitudeTargetMsg(mask, q, (0, 0, 0), 0.5), 0.2)
    assert apm.angle[0] is None, 'init(true): back to level, climb rate 0'


def test_px4_failsafe_waits_for_com_of_loss_t_not_for_the_stream_rate():
    px4 = Px4(hover_throttle=0.5, params={'COM_OF_LOSS_T': 3.0})
    px4.armed = True
    msg = AttitudeTargetMsg(p.TYPEMASK_RATES_IGNORE, LEVEL, (0, 0, 0), 0.5)
    for k in range(30):
        px4.on_attitude_target(msg, k * 0.02)
    assert px4.command(p.MAV_CMD_DO_SET_MODE, [1, 6, 0], False, 0.6) == p.MAV_RESULT_ACCEPTED
    px4.update(HOVERING, False, 2.0)          # a 1.4 s gap: the rate is 0 Hz, but COM_OF_LOSS_T is 3 s
    assert px4.mode == 'OFFBOARD'
    px4.update(HOVERING, False, 3.7)
    assert px4.mode == 'POSCTL'               # COM_OBL_RC_ACT 0 (Position): POSCTL, also without RC


def test_px4_drops_roll_and_pitch_rates_with_an_attitude_when_asked():
    """mavlink_receiver.cpp handle_message_set_attitude_target: with the attitude set, only the body yaw rate
    survives (yaw_sp_move_rate); roll and pitch rates reach nothing. The emulator's default feeds all three."""
    msg = AttitudeTargetMsg(0, LEVEL, (0.3, -0.2, 0.1), 0.5)
    fed = Px4(hover_throttle=0.5)
    fed.on_attitude_target(msg, 0.0)
    dropped = Px4(hover_throttle=0.5, rp_rates_with_attitude=False)
    dropped.on_attitude_target(msg, 0.0)
    assert np.allclose(fed.setpoint[2], [0.3, 0.2, -0.1])          # FRD -> FLU
    assert np.allclose(dropped.setpoint[2], [0.0, 0.0, -0.1])


@pytest.mark.parametrize('flavour, defaults, enabled', [
    ('px4', {'EKF2_EV_CTRL': 15, 'EKF2_HGT_REF': 1, 'EKF2_EV_DELAY': 0.0, 'EKF2_GPS_CTRL': 7},
     {'EKF2_HGT_REF': 3, 'EKF2_GPS_CTRL': 0, 'EKF2_EV_DELAY': 20.0}),
    ('ardupilot', {'VISO_TYPE': 0, 'VISO_DELAY_MS': 10, 'EK3_SRC1_POSXY': 3, 'EK3_SRC1_VELXY': 3,
                   'EK3_SRC1_POSZ': 1, 'EK3_SRC1_VELZ': 3, 'EK3_SRC1_YAW': 1},
     {'VISO_TYPE': 1, 'EK3_SRC1_POSXY': 6, 'EK3_SRC1_VELXY': 6, 'EK3_SRC1_POSZ': 6, 'EK3_SRC1_YAW': 6}),
])
def test_external_vision_parameters_have_the_autopilots_defaults_and_are_settable(flavour, defaults, enabled):
    from quad_vehicle_emu.autopilots import make_autopilot
    params = make_autopilot(flavour, 0.5).params
    assert {name: params[name] for name in defaults} == pytest.approx(defaults)
    for name, value in enabled.items():
        decoded = params.decode(name, *params.encode(name))   # PARAM_VALUE round trip, as PARAM_SET carries it
        assert decoded == params[name]
        params.set(name, value)
        assert params[name] == value


GROUND = State(position=np.array([0.0, 0.0, 0.0]))


def test_px4_without_gps_has_a_position_while_vision_is_fused_and_loses_it_after_the_no_aid_timeout():
    px4 = Px4(hover_throttle=0.5, params={'EKF2_GPS_CTRL': 0})
    assert px4.command(p.MAV_CMD_COMPONENT_ARM_DISARM, [1, 0], True, 0.0) == p.MAV_RESULT_DENIED
    assert [t for _, t in px4.log[-2:]] == ['Preflight Fail: No valid local position estimate',
                                           'Arming denied: Resolve system health failures first']
    px4.on_external_pose(1.0)
    assert px4.has_position(1.0 + 4.9) and not px4.has_position(1.0 + 5.1)
    assert px4.command(p.MAV_CMD_COMPONENT_ARM_DISARM, [1, 0], True, 2.0) == p.MAV_RESULT_ACCEPTED
    px4.params.set('EKF2_EV_CTRL', 14)          # horizontal position not fused
    assert not px4.has_position(2.0)


def test_arducopter_position_modes_need_gps_or_external_nav():
    apm = ArduCopter(hover_throttle=0.5, params={'EK3_SRC1_POSXY': 6, 'VISO_TYPE': 1})
    assert apm.command(p.MAV_CMD_DO_SET_MODE, [1, 4, 0], True, 0.0) == p.MAV_RESULT_FAILED
    assert apm.log[-1][1] == 'Mode change to GUIDED failed: requires position'
    assert apm.command(p.MAV_CMD_DO_SET_MODE, [1, 20, 0], True, 0.0) == p.MAV_RESULT_ACCEPTED   # GUIDED_NOGPS
    apm.on_external_pose(1.0)
    assert apm.command(p.MAV_CMD_DO_SET_MODE, [1, 4, 0], True, 1.5) == p.MAV_RESULT_ACCEPTED
    assert apm.command(p.MAV_CMD_COMPONENT_ARM_DISARM, [1, 0], True, 8.5) == p.MAV_RESULT_FAILED
    assert apm.log[-1][1] == 'PreArm: Need Position Estimate'
    assert apm.command(p.MAV_CMD_COMPONENT_ARM_DISARM, [1, 0], True, 7.5) == p.MAV_RESULT_ACCEPTED
    apm = ArduCopter(hover_throttle=0.5, params={'EK3_SRC1_POSXY': 6})   # VISO_TYPE 0: the pose is not taken
    apm.on_external_pose(1.0)
    assert not apm.has_position(1.0)


def test_px4_descends_when_the_vision_pose_stops_in_hold():
    px4 = Px4(hover_throttle=0.5, params={'EKF2_GPS_CTRL': 0})
    px4.on_external_pose(0.0)
    assert px4.command(p.MAV_CMD_COMPONENT_ARM_DISARM, [1, 0], True, 0.0) == p.MAV_RESULT_ACCEPTED
    px4.update(HOVERING, False, 4.9)
    assert px4.mode == 'AUTO.LOITER'
    sp = px4.update(State(position=np.array([0.0, 0.0, 1.0]), velocity=np.array([0.5, 0.0, 0.0])), False, 5.1)
    assert px4.mode == 'AUTO.LAND', 'Hold cannot run without a position: Descend (reported as AUTO.LAND)'
    assert sp.specific_force_mps2 < GRAVITY_MPS2 * 1.01
    assert abs(sp.quaternion[0]) < 1e-9 and abs(sp.quaternion[1]) < 1e-9, 'level: nothing holds it horizontally'


def test_arducopter_lands_one_second_after_the_ekf_loses_the_position_in_guided():
    apm = ArduCopter(hover_throttle=0.5, params={'EK3_SRC1_POSXY': 6, 'VISO_TYPE': 1})
    apm.on_external_pose(0.0)
    assert apm.command(p.MAV_CMD_DO_SET_MODE, [1, 4, 0], True, 0.0) == p.MAV_RESULT_ACCEPTED
    assert apm.command(p.MAV_CMD_COMPONENT_ARM_DISARM, [1, 0], True, 0.0) == p.MAV_RESULT_ACCEPTED
    apm.update(HOVERING, False, 7.5)
    apm.update(HOVERING, False, 8.4)
    assert apm.mode == 'GUIDED'
    apm.update(HOVERING, False, 8.6)
    assert apm.mode == 'LAND' and apm.log[-2][1] == 'EKF Failsafe'


@pytest.mark.parametrize('autopilot,params,axes', [
    (Px4, {}, (False, False, False)),                                          # GPS on: the GPS-like estimate
    (Px4, {'EKF2_GPS_CTRL': 0, 'EKF2_EV_CTRL': 3, 'EKF2_HGT_REF': 3}, (True, True, True)),
    (Px4, {'EKF2_GPS_CTRL': 0, 'EKF2_EV_CTRL': 1}, (True, True, False)),      # height from the GPS / baro
    (ArduCopter, {}, (False, False, False)),
    (ArduCopter, {'VISO_TYPE': 1, 'EK3_SRC1_POSXY': 6, 'EK3_SRC1_POSZ': 6}, (True, True, True)),
    (ArduCopter, {'VISO_TYPE': 1, 'EK3_SRC1_POSXY': 6}, (True, True, False)),  # height from the barometer
    (ArduCopter, {'EK3_SRC1_POSXY': 6, 'EK3_SRC1_POSZ': 6}, (False, False, False)),   # VISO_TYPE 0: no pose
])
def test_the_vision_axes_follow_the_position_source_parameters(autopilot, params, axes):
    assert autopilot(0.5, params).vision_axes() == axes
