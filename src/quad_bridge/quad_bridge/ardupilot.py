"""ArduPilot Copter as a bridge backend.

Modes: HEARTBEAT.custom_mode is the Copter mode number (ArduCopter/mode.h: GUIDED 4, LAND 9,
GUIDED_NOGPS 20); DO_SET_MODE takes it as param2. Both GUIDED and GUIDED_NOGPS fly SET_ATTITUDE_TARGET
(ModeGuided::set_angle), so both obey our setpoints; `offboard` asks for GUIDED_NOGPS.
Thrust field (ModeGuided::set_attitude_target_provides_thrust): with GUID_OPTIONS bit 3
(SetAttitudeTarget_ThrustAsThrust, value 8) a thrust in [0, 1] that the attitude controller multiplies by
1/cos(target tilt) when ATC_ANGLE_BOOST = 1 (AC_AttitudeControl_Multi::get_throttle_boosted); with bit 3
clear a climb rate: 0.5 holds, 1 climbs at WPNAV_SPEED_UP, 0 descends at WPNAV_SPEED_DN.
Telemetry: ArduCopter has no HIGHRES_IMU stream ("No ap_message for mavlink id 105"); SCALED_IMU and
RAW_IMU both carry mG and mrad/s (GCS_Common.cpp send_scaled_imu / send_raw_imu).
SYS_STATUS: the pre-arm bit is present always, enabled when arming checks are on, healthy when armed or
the checks pass (GCS.cpp get_sensor_status_flags).
"""

from dataclasses import replace

import numpy as np

from quad_bridge.backend import MAV_SYS_STATUS_PREARM_CHECK as PREARM
from quad_bridge.backend import Backend, BridgeConfig, ParamCheck, StreamGroup, tilt_cos
from quad_common import rotations
from quad_common.types import GRAVITY_MPS2, AttitudeSetpoint

MAV_AUTOPILOT_ARDUPILOTMEGA = 3
COPTER_MODES = {0: 'STABILIZE', 1: 'ACRO', 2: 'ALT_HOLD', 3: 'AUTO', 4: 'GUIDED', 5: 'LOITER', 6: 'RTL', 7: 'CIRCLE',
                9: 'LAND', 11: 'DRIFT', 13: 'SPORT', 14: 'FLIP', 15: 'AUTOTUNE', 16: 'POSHOLD', 17: 'BRAKE',
                18: 'THROW', 19: 'AVOID_ADSB', 20: 'GUIDED_NOGPS', 21: 'SMART_RTL'}
GUID_OPTIONS_THRUST_BIT = 1 << 3   # SetAttitudeTarget_ThrustAsThrust
EXTERNAL_NAV = 6                   # AP_NavEKF_Source SourceXY/SourceZ/SourceYaw ExternalNav
ANGLE_BOOST_COS_MIN = 0.1          # get_throttle_boosted: 1 / constrain(cos(tilt), 0.1, 1)


def climb_rate_to_thrust(climb_rate_mps: float, speed_up_mps: float, speed_down_mps: float) -> float:
    """0.5 holds altitude, 1 climbs at speed_up_mps, 0 descends at speed_down_mps (linear in between)."""
    if climb_rate_mps >= 0.0:
        return float(np.clip(0.5 + 0.5 * climb_rate_mps / speed_up_mps, 0.5, 1.0))
    return float(np.clip(0.5 + 0.5 * climb_rate_mps / speed_down_mps, 0.0, 0.5))


def thrust_to_climb_rate(thrust: float, speed_up_mps: float, speed_down_mps: float) -> float:
    thrust = float(np.clip(thrust, 0.0, 1.0))
    return (thrust - 0.5) * 2.0 * (speed_up_mps if thrust >= 0.5 else speed_down_mps)


def climb_rate_command(specific_force_mps2, quaternion, vertical_velocity_mps, lead_s) -> float:
    """The vertical speed the commanded vertical acceleration f cos(tilt) - g reaches after lead_s."""
    return float(vertical_velocity_mps + lead_s * (specific_force_mps2 * tilt_cos(quaternion) - GRAVITY_MPS2))


class ArduPilot(Backend):
    autopilot = MAV_AUTOPILOT_ARDUPILOTMEGA
    key = 'ardupilot'
    name = 'ArduPilot'
    offboard_mode = 'GUIDED_NOGPS'
    obeying_modes = frozenset({'GUIDED', 'GUIDED_NOGPS'})
    land_mode = 'LAND'
    prestream = False
    semantic_params = ('GUID_OPTIONS', 'MOT_THST_HOVER', 'ATC_ANGLE_BOOST')
    external_pose_params = ('VISO_TYPE', 'EK3_SRC1_POSXY', 'EK3_SRC1_VELXY', 'EK3_SRC1_POSZ', 'EK3_SRC1_YAW')
    telemetry = (StreamGroup('odometry', (('LOCAL_POSITION_NED', 'ATTITUDE_QUATERNION'), ('ODOMETRY',))),
                 StreamGroup('imu', (('SCALED_IMU',), ('RAW_IMU',))),
                 StreamGroup('status', (('SYS_STATUS',),), share=0.0),
                 StreamGroup('battery', (('BATTERY_STATUS',),), share=0.0))

    def external_pose_messages(self, pose):
        """VISION_POSITION_ESTIMATE (NED position, FRD -> NED roll / pitch / yaw) and, with a velocity,
        VISION_SPEED_ESTIMATE (NED): GCS_MAVLINK handle_vision_position_estimate / handle_vision_speed_estimate
        into AP_VisualOdom (VISO_TYPE 1, MAVLink). Covariances zero: ArduPilot sums cov[0] + cov[6] + cov[11]
        into one error, which a NaN would poison; zero leaves VISO_POS_M_NSE / VISO_VEL_M_NSE as the floor."""
        roll, pitch, yaw = (float(a) for a in rotations.to_euler(pose.quaternion_ned_frd))
        x, y, z = (float(c) for c in pose.position_ned)
        out = [('vision_position_estimate', (pose.time_us, x, y, z, roll, pitch, yaw, [0.0] * 21, 0))]
        if pose.velocity_frd is not None:
            vx, vy, vz = (float(c) for c in pose.velocity_ned)
            out.append(('vision_speed_estimate', (pose.time_us, vx, vy, vz, [0.0] * 9, 0)))
        return tuple(out)

    def mode_name(self, custom_mode_word):
        return COPTER_MODES.get(int(custom_mode_word), f'MODE_{custom_mode_word}')

    def mode_params(self, name):
        modes = {v: k for k, v in COPTER_MODES.items()}
        if name.upper() not in modes:
            raise ValueError(f'ArduPilot Copter mode {name!r} unknown: one of {", ".join(COPTER_MODES.values())}')
        return modes[name.upper()], 0

    def custom_mode(self, name):
        return self.mode_params(name)[0]

    def hold_mode(self, stale_action):
        """Without a position estimate (GUIDED_NOGPS) there is no hold: always LAND."""
        return self.land_mode

    def prearm_ready(self, present, enabled, health):
        if not enabled & PREARM:
            return None  # ARMING_CHECK = 0: no verdict
        return bool(health & PREARM)

    def thrust(self, sp: AttitudeSetpoint, config: BridgeConfig, vertical_velocity_mps=0.0):
        """Thrust mode: T = hover * f * cos(tilt) / g, which the vehicle's angle boost multiplies by 1/cos(tilt)
        back to hover * f / g (without boost: T = hover * f / g). Climb-rate mode: the climb rate the commanded
        vertical acceleration reaches after climb_rate_lead_s, as 0.5 +- 0.5 rate / WPNAV_SPEED_UP/DN."""
        if config.ardupilot_thrust_mode == 'climb_rate':
            rate = climb_rate_command(sp.specific_force_mps2, sp.quaternion, vertical_velocity_mps,
                                      config.climb_rate_lead_s)
            return climb_rate_to_thrust(rate, config.ardupilot_speed_up_mps, config.ardupilot_speed_down_mps)
        c = max(tilt_cos(sp.quaternion), ANGLE_BOOST_COS_MIN) if config.angle_boost else 1.0
        return float(np.clip(config.hover_throttle * sp.specific_force_mps2 * c / GRAVITY_MPS2, 0.0, 1.0))

    def specific_force(self, thrust, config, quaternion):
        f = float(np.clip(thrust, 0.0, 1.0)) * GRAVITY_MPS2 / config.hover_throttle
        return f / max(tilt_cos(quaternion), ANGLE_BOOST_COS_MIN) if config.angle_boost else f

    def _check(self, values, config, adopt):
        problems, notes = [], []
        options = int(values['GUID_OPTIONS'])
        vehicle_mode = 'thrust' if options & GUID_OPTIONS_THRUST_BIT else 'climb_rate'
        if vehicle_mode != config.ardupilot_thrust_mode:
            if adopt:
                notes.append(f'ardupilot_thrust_mode {config.ardupilot_thrust_mode} -> {vehicle_mode} '
                             f'(GUID_OPTIONS = {options})')
                config = replace(config, ardupilot_thrust_mode=vehicle_mode)
            else:
                meaning = 'thrust' if vehicle_mode == 'thrust' else 'a climb rate'
                problems.append(f'GUID_OPTIONS = {options} (bit 3 {"set" if options & 8 else "clear"}: the thrust '
                                f'field is {meaning}) contradicts ardupilot_thrust_mode = '
                                f'{config.ardupilot_thrust_mode}: '
                                f'set GUID_OPTIONS {"|" if config.ardupilot_thrust_mode == "thrust" else "&~"}= 8 or '
                                f'ardupilot_thrust_mode: {vehicle_mode}')
        boost = bool(values['ATC_ANGLE_BOOST'])
        if boost != config.angle_boost:
            notes.append(f'ATC_ANGLE_BOOST = {int(boost)}: thrust sent {"with" if boost else "without"} cos(tilt)')
            config = replace(config, angle_boost=boost)
        if config.ardupilot_thrust_mode == 'thrust':
            config = self._hover('MOT_THST_HOVER', values, config, adopt, problems, notes)
        return ParamCheck(tuple(problems), tuple(notes), config)

    def _check_external_pose(self, values):
        """VISO_TYPE 1 (MAVLink: AP_VisualOdom takes VISION_POSITION_ESTIMATE), EKF3 source set 1 on it
        (AP_NavEKF_Source: 6 = ExternalNav): POSXY 6, VELXY 6 or 0 (none), POSZ 6 (1, the barometer: noted),
        YAW 6 (1, the compass: noted)."""
        problems, notes = [], []
        viso, posxy, velxy = int(values['VISO_TYPE']), int(values['EK3_SRC1_POSXY']), int(values['EK3_SRC1_VELXY'])
        posz, yaw = int(values['EK3_SRC1_POSZ']), int(values['EK3_SRC1_YAW'])
        if viso != 1:
            problems.append(f'VISO_TYPE = {viso}: the vehicle does not take the external pose (set VISO_TYPE = 1)')
        if posxy != EXTERNAL_NAV:
            problems.append(f'EK3_SRC1_POSXY = {posxy}: horizontal position is not from the external pose '
                            f'(set {EXTERNAL_NAV})')
        if velxy not in (0, EXTERNAL_NAV):
            problems.append(f'EK3_SRC1_VELXY = {velxy}: horizontal velocity from another source (set {EXTERNAL_NAV} '
                            'or 0)')
        for name, value, other in (('EK3_SRC1_POSZ', posz, 'the barometer'), ('EK3_SRC1_YAW', yaw, 'the compass')):
            if value == 1:
                notes.append(f'{name} = 1: from {other}, not the external pose ({EXTERNAL_NAV})')
            elif value != EXTERNAL_NAV:
                problems.append(f'{name} = {value}: not from the external pose (set {EXTERNAL_NAV})')
        return tuple(problems), tuple(notes)
