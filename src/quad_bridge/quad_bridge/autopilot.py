"""What differs between PX4 and ArduPilot Copter: mode encoding, which modes we use, thrust semantics.

PX4 packs its mode into HEARTBEAT.custom_mode: main mode in bits 16-23, sub mode in bits 24-31.
ArduPilot Copter's custom_mode is the plain mode number (GUIDED 4, LAND 9, GUIDED_NOGPS 20).
MAV_CMD_DO_SET_MODE takes param1 = MAV_MODE_FLAG_CUSTOM_MODE_ENABLED (1) and the mode as small
values: PX4 main mode in param2 and sub mode in param3, ArduPilot the mode number in param2.
"""

import numpy as np

from quad_common import rotations
from quad_common.types import GRAVITY_MPS2

MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_AUTOPILOT_PX4 = 12
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_MODE_FLAG_SAFETY_ARMED = 128

PX4_MAIN_MODES = {1: 'MANUAL', 2: 'ALTCTL', 3: 'POSCTL', 4: 'AUTO', 5: 'ACRO', 6: 'OFFBOARD', 7: 'STABILIZED',
                  8: 'RATTITUDE'}
PX4_AUTO_SUB_MODES = {1: 'READY', 2: 'TAKEOFF', 3: 'LOITER', 4: 'MISSION', 5: 'RTL', 6: 'LAND', 8: 'FOLLOW_TARGET',
                      9: 'PRECLAND'}
PX4_OFFBOARD = (6, 0)
PX4_LOITER = (4, 3)
PX4_LAND = (4, 6)

COPTER_MODES = {0: 'STABILIZE', 1: 'ACRO', 2: 'ALT_HOLD', 3: 'AUTO', 4: 'GUIDED', 5: 'LOITER', 6: 'RTL', 7: 'CIRCLE',
                9: 'LAND', 11: 'DRIFT', 13: 'SPORT', 14: 'FLIP', 15: 'AUTOTUNE', 16: 'POSHOLD', 17: 'BRAKE',
                18: 'THROW', 19: 'AVOID_ADSB', 20: 'GUIDED_NOGPS', 21: 'SMART_RTL'}
COPTER_GUIDED = 4
COPTER_LAND = 9
COPTER_GUIDED_NOGPS = 20
GUID_OPTIONS_THRUST_BIT = 1 << 3  # "SetAttitudeTarget interprets thrust as thrust"
ANGLE_BOOST_COS_MIN = 0.1         # ArduPilot limits its 1/cos(tilt) boost to 10x


def px4_custom_mode(main_mode: int, sub_mode: int = 0) -> int:
    return (int(main_mode) & 0xFF) << 16 | (int(sub_mode) & 0xFF) << 24


def px4_decode(custom_mode: int) -> tuple[int, int]:
    """(main mode, sub mode) of a PX4 custom_mode word."""
    return (int(custom_mode) >> 16) & 0xFF, (int(custom_mode) >> 24) & 0xFF


def mode_name(autopilot: int, custom_mode: int) -> str:
    if autopilot == MAV_AUTOPILOT_PX4:
        main, sub = px4_decode(custom_mode)
        name = PX4_MAIN_MODES.get(main, f'MAIN_{main}')
        if main == 4:
            name += '.' + PX4_AUTO_SUB_MODES.get(sub, f'SUB_{sub}')
        return name
    if autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA:
        return COPTER_MODES.get(int(custom_mode), f'MODE_{custom_mode}')
    return f'UNKNOWN_{custom_mode}'


def mode_from_name(autopilot: int, name: str) -> tuple[int, int]:
    """(param2, param3) of MAV_CMD_DO_SET_MODE for a mode name (as mode_name writes it)."""
    if autopilot == MAV_AUTOPILOT_PX4:
        main_name, _, sub_name = name.upper().partition('.')
        mains = {v: k for k, v in PX4_MAIN_MODES.items()}
        subs = {v: k for k, v in PX4_AUTO_SUB_MODES.items()}
        if main_name not in mains or (sub_name and sub_name not in subs):
            raise ValueError(f'PX4 mode {name!r} unknown: one of {", ".join(PX4_MAIN_MODES.values())}, AUTO.<sub>')
        return mains[main_name], subs.get(sub_name, 0)
    if autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA:
        modes = {v: k for k, v in COPTER_MODES.items()}
        if name.upper() not in modes:
            raise ValueError(f'ArduPilot Copter mode {name!r} unknown: one of {", ".join(COPTER_MODES.values())}')
        return modes[name.upper()], 0
    raise ValueError(f'autopilot {autopilot} is neither PX4 (12) nor ArduPilot (3)')


def custom_mode_of(autopilot: int, param2: float, param3: float) -> int:
    """The HEARTBEAT.custom_mode a vehicle reports after DO_SET_MODE(1, param2, param3)."""
    if autopilot == MAV_AUTOPILOT_PX4:
        return px4_custom_mode(int(param2), int(param3))
    return int(param2)


def offboard_mode(autopilot: int) -> str:
    """The mode that flies our attitude/thrust setpoints."""
    return 'OFFBOARD' if autopilot == MAV_AUTOPILOT_PX4 else 'GUIDED_NOGPS'


def land_mode(autopilot: int) -> str:
    return 'AUTO.LAND' if autopilot == MAV_AUTOPILOT_PX4 else 'LAND'


def hold_mode(autopilot: int) -> str:
    """PX4 holds position in AUTO.LOITER; ArduPilot without position (GUIDED_NOGPS) can only land."""
    return 'AUTO.LOITER' if autopilot == MAV_AUTOPILOT_PX4 else 'LAND'


# --- thrust semantics ---------------------------------------------------------------------------------

def tilt_cos(quaternion) -> float:
    """cos of the angle between body z and world z: R[2, 2] (the same in ENU/FLU and NED/FRD)."""
    return float(rotations.to_matrix(quaternion)[2, 2])


def thrust_px4(specific_force_mps2: float, hover_throttle: float) -> float:
    """PX4 offboard collective thrust in [0, 1]: T = thr_hover * f / g (linear about hover)."""
    return float(np.clip(hover_throttle * specific_force_mps2 / GRAVITY_MPS2, 0.0, 1.0))


def thrust_ardupilot(specific_force_mps2: float, hover_throttle: float, quaternion) -> float:
    """ArduPilot GUIDED_NOGPS thrust (GUID_OPTIONS bit 3): the vehicle multiplies it by 1/cos(tilt)
    itself (angle boost, ATC_ANGLE_BOOST=1), and f already is the full thrust along the tilted body z,
    so send T = thr_hover * f cos(tilt) / g, so that the boosted thrust equals thr_hover * f / g."""
    c = max(tilt_cos(quaternion), ANGLE_BOOST_COS_MIN)
    return float(np.clip(hover_throttle * specific_force_mps2 * c / GRAVITY_MPS2, 0.0, 1.0))


def climb_rate_to_thrust(climb_rate_mps: float, speed_up_mps: float, speed_down_mps: float) -> float:
    """ArduPilot GUIDED_NOGPS without GUID_OPTIONS bit 3: 0.5 holds altitude, 1 climbs at WPNAV_SPEED_UP,
    0 descends at WPNAV_SPEED_DN (linear in between)."""
    if climb_rate_mps >= 0.0:
        return float(np.clip(0.5 + 0.5 * climb_rate_mps / speed_up_mps, 0.5, 1.0))
    return float(np.clip(0.5 + 0.5 * climb_rate_mps / speed_down_mps, 0.0, 0.5))


def thrust_to_climb_rate(thrust: float, speed_up_mps: float, speed_down_mps: float) -> float:
    """Inverse of climb_rate_to_thrust (what ArduPilot does with the thrust field)."""
    thrust = float(np.clip(thrust, 0.0, 1.0))
    if thrust >= 0.5:
        return (thrust - 0.5) * 2.0 * speed_up_mps
    return (thrust - 0.5) * 2.0 * speed_down_mps


def climb_rate_command(specific_force_mps2: float, quaternion, vertical_velocity_mps: float, lead_s: float) -> float:
    """A climb rate for a thrust setpoint: the vertical velocity the commanded vertical acceleration
    f cos(tilt) - g reaches after lead_s, v_z + lead_s (f cos(tilt) - g)."""
    return float(vertical_velocity_mps + lead_s * (specific_force_mps2 * tilt_cos(quaternion) - GRAVITY_MPS2))


def specific_force_from_thrust(autopilot: int, thrust: float, hover_throttle: float, quaternion=None) -> float:
    """What a vehicle makes of a normalised thrust (the inverse of thrust_px4 / thrust_ardupilot)."""
    f = float(np.clip(thrust, 0.0, 1.0)) * GRAVITY_MPS2 / hover_throttle
    if autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA:
        f /= max(tilt_cos(quaternion), ANGLE_BOOST_COS_MIN)
    return f
