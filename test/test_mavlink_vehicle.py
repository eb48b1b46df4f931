"""The emulated autopilot of mavlink_vehicle (no sockets): PX4 offboard rules, ArduPilot guided semantics,
landing. It must behave like the real ones for the bridge tests to mean anything."""

import math

import numpy as np
import pytest

from quad_bridge import autopilot as ap
from quad_bridge import frames
from quad_bridge.mavlink_client import mavlink
from quad_common import rotations
from quad_common.types import State
from quad_sim.mavlink_vehicle import OnboardAutopilot

LEVEL_NED = frames.quaternion_enu_to_ned([0.0, 0.0, 0.0, 1.0])
HOVERING = State(position=np.array([0.0, 0.0, 1.0]))


def set_mode(autopilot, name, now_s, landed=False):
    return autopilot.command(mavlink.MAV_CMD_DO_SET_MODE, [1, *ap.mode_from_name(autopilot.autopilot, name)],
                             landed, now_s)


def stream(autopilot, t0, t1, thrust=0.5, q_ned=LEVEL_NED, rate_hz=50.0):
    for k in range(int((t1 - t0) * rate_hz)):
        autopilot.on_attitude_target(q_ned, [0, 0, 0], thrust, True, t0 + k / rate_hz)


def test_px4_offboard_needs_a_live_stream_and_is_left_after_loss():
    px4 = OnboardAutopilot('px4', hover_throttle=0.4)
    px4.armed = True
    assert set_mode(px4, 'OFFBOARD', 1.0) == mavlink.MAV_RESULT_DENIED
    stream(px4, 1.0, 2.0, thrust=0.4)
    assert set_mode(px4, 'OFFBOARD', 2.0) == mavlink.MAV_RESULT_ACCEPTED
    assert px4.custom_mode == ap.px4_custom_mode(6)
    sp = px4.update(HOVERING, landed=False, now_s=2.0)
    assert sp.specific_force_mps2 == pytest.approx(9.81)          # T = 0.4 = hover -> f = g
    px4.update(HOVERING, landed=False, now_s=3.5)                   # COM_OF_LOSS_T = 1 s passed
    assert px4.mode == 'AUTO.LAND'


def test_ardupilot_thrust_is_boosted_and_guided_timeout_levels_without_leaving_the_mode():
    apm = OnboardAutopilot('ardupilot', hover_throttle=0.5, guid_options=8)
    apm.armed = True
    assert set_mode(apm, 'GUIDED_NOGPS', 0.0) == mavlink.MAV_RESULT_ACCEPTED  # no stream needed
    assert apm.custom_mode == 20
    q_enu = rotations.from_euler(math.radians(30.0), 0.0, 0.0)
    stream(apm, 0.0, 0.5, thrust=0.5, q_ned=frames.quaternion_enu_to_ned(q_enu))
    sp = apm.update(HOVERING, landed=False, now_s=0.5)
    assert sp.specific_force_mps2 == pytest.approx(9.81 / math.cos(math.radians(30.0)))
    sp = apm.update(HOVERING, landed=False, now_s=4.0)               # GUID_TIMEOUT = 3 s passed
    assert apm.mode == 'GUIDED_NOGPS'
    assert math.degrees(math.acos(ap.tilt_cos(sp.quaternion))) == pytest.approx(0.0, abs=1e-9)


def test_ardupilot_climb_rate_semantics_without_bit_3():
    apm = OnboardAutopilot('ardupilot', hover_throttle=0.5, guid_options=0)
    apm.armed = True
    set_mode(apm, 'GUIDED_NOGPS', 0.0)
    stream(apm, 0.0, 0.5, thrust=0.5)
    assert apm.update(HOVERING, False, 0.5).specific_force_mps2 == pytest.approx(9.81)  # hold altitude
    stream(apm, 0.5, 1.0, thrust=1.0)
    climbing = apm.update(HOVERING, False, 1.0).specific_force_mps2
    assert climbing > 9.81                                            # climb at WPNAV_SPEED_UP


def test_land_descends_and_disarms_on_the_ground():
    px4 = OnboardAutopilot('px4', hover_throttle=0.5)
    px4.armed = True
    assert set_mode(px4, 'AUTO.LAND', 0.0) == mavlink.MAV_RESULT_ACCEPTED
    sp = px4.update(HOVERING, landed=False, now_s=0.1)
    assert sp.specific_force_mps2 < 9.81                              # starts down at 0.7 m/s
    assert px4.update(HOVERING, landed=True, now_s=5.0) is None and not px4.armed
    disarm_in_air = px4.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, [1, 0], False, 6.0)
    assert disarm_in_air == mavlink.MAV_RESULT_ACCEPTED and px4.armed
    assert px4.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, [0, 0], False, 7.0) == mavlink.MAV_RESULT_DENIED


def test_malformed_setpoints_are_refused():
    px4 = OnboardAutopilot('px4', hover_throttle=0.5)
    with pytest.raises(ValueError):
        px4.on_attitude_target([0, 0, 0, 0], [0, 0, 0], 0.5, True, 0.0)
    with pytest.raises(ValueError):
        px4.on_attitude_target(LEVEL_NED, [0, 0, 0], math.nan, True, 0.0)
    assert set_mode(px4, 'OFFBOARD', 0.0) == mavlink.MAV_RESULT_DENIED
