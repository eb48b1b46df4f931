"""PX4 multicopter as a bridge backend.

Modes: HEARTBEAT.custom_mode packs the main mode in bits 16-23 and the sub mode in bits 24-31
(PX4 src/modules/commander/px4_custom_mode.h); DO_SET_MODE takes them as param2 / param3.
OFFBOARD needs a live setpoint stream before the switch (PX4 docs "Offboard mode": > 2 Hz), and PX4
switches itself back to OFFBOARD after a disarm in it (its user-intended mode), hence arm_refusal.
Thrust: collective thrust normalised to [0, 1], linear about hover: T = MPC_THR_HOVER * f / g.
SYS_STATUS: PX4 sets only the health bit of MAV_SYS_STATUS_PREARM_CHECK, when arming is possible in the
current mode (src/modules/mavlink/streams/SYS_STATUS.hpp, health_report.can_arm_mode_flags).
"""

import struct

import numpy as np

from quad_bridge.backend import Backend, BridgeConfig, ParamCheck, StreamGroup
from quad_bridge.frames import to_mavlink_quaternion
from quad_bridge.setpoint_stream import FIRST_RESEND_PERIODS
from quad_common.types import GRAVITY_MPS2, AttitudeSetpoint

MAV_AUTOPILOT_PX4 = 12
MAIN_MODES = {1: 'MANUAL', 2: 'ALTCTL', 3: 'POSCTL', 4: 'AUTO', 5: 'ACRO', 6: 'OFFBOARD', 7: 'STABILIZED',
              8: 'RATTITUDE'}
AUTO_SUB_MODES = {1: 'READY', 2: 'TAKEOFF', 3: 'LOITER', 4: 'MISSION', 5: 'RTL', 6: 'LAND', 8: 'FOLLOW_TARGET',
                  9: 'PRECLAND'}
MAV_PARAM_TYPE_REAL32 = 9
MAV_FRAME_BODY_FRD = 12
MAV_FRAME_LOCAL_FRD = 20
MAV_ESTIMATOR_TYPE_VISION = 2   # MOCAP (6) goes to PX4's vehicle_mocap_odometry, which EKF2 does not fuse
NAN = float('nan')


def custom_mode(main_mode: int, sub_mode: int = 0) -> int:
    return (int(main_mode) & 0xFF) << 16 | (int(sub_mode) & 0xFF) << 24


def decode(custom_mode_word: int) -> tuple[int, int]:
    """(main mode, sub mode) of a PX4 custom_mode word."""
    return (int(custom_mode_word) >> 16) & 0xFF, (int(custom_mode_word) >> 24) & 0xFF


class Px4(Backend):
    autopilot = MAV_AUTOPILOT_PX4
    key = 'px4'
    name = 'PX4'
    offboard_mode = 'OFFBOARD'
    obeying_modes = frozenset({'OFFBOARD'})
    land_mode = 'AUTO.LAND'
    prestream = True
    semantic_params = ('MPC_THR_HOVER', 'COM_OF_LOSS_T')
    external_pose_params = ('EKF2_EV_CTRL', 'EKF2_HGT_REF', 'EKF2_GPS_CTRL', 'EKF2_EV_DELAY')
    telemetry = (StreamGroup('odometry', (('LOCAL_POSITION_NED', 'ATTITUDE_QUATERNION'), ('ODOMETRY',))),
                 StreamGroup('imu', (('HIGHRES_IMU',), ('SCALED_IMU',))),
                 StreamGroup('status', (('SYS_STATUS',),), share=0.0),
                 StreamGroup('battery', (('BATTERY_STATUS',),), share=0.0))

    def external_pose_messages(self, pose):
        """ODOMETRY: pose in MAV_FRAME_LOCAL_FRD (EKF2 rotates a local frame into its own unless it fuses the
        external heading), velocity in MAV_FRAME_BODY_FRD (NaN: none), covariances NaN (unknown: EKF2 takes
        EKF2_EVP_NOISE / EKF2_EVV_NOISE / EKF2_EVA_NOISE), estimator_type VISION (mavlink_receiver.cpp
        handle_message_odometry publishes it to vehicle_visual_odometry)."""
        v = (NAN, NAN, NAN) if pose.velocity_frd is None else tuple(float(c) for c in pose.velocity_frd)
        x, y, z = (float(c) for c in pose.position_ned)
        return (('odometry', (pose.time_us, MAV_FRAME_LOCAL_FRD, MAV_FRAME_BODY_FRD, x, y, z,
                              to_mavlink_quaternion(pose.quaternion_ned_frd), *v, NAN, NAN, NAN,
                              [NAN] + [0.0] * 20, [NAN] + [0.0] * 20, 0, MAV_ESTIMATOR_TYPE_VISION, 0)),)

    def mode_name(self, custom_mode_word):
        main, sub = decode(custom_mode_word)
        name = MAIN_MODES.get(main, f'MAIN_{main}')
        if main == 4:
            name += '.' + AUTO_SUB_MODES.get(sub, f'SUB_{sub}')
        return name

    def mode_params(self, name):
        main_name, _, sub_name = name.upper().partition('.')
        mains = {v: k for k, v in MAIN_MODES.items()}
        subs = {v: k for k, v in AUTO_SUB_MODES.items()}
        if main_name not in mains or (sub_name and sub_name not in subs):
            raise ValueError(f'PX4 mode {name!r} unknown: one of {", ".join(MAIN_MODES.values())}, AUTO.<sub>')
        return mains[main_name], subs.get(sub_name, 0)

    def custom_mode(self, name):
        return custom_mode(*self.mode_params(name))

    def hold_mode(self, stale_action):
        return 'AUTO.LOITER' if stale_action == 'hold' else self.land_mode

    def arm_refusal(self, mode, handing_over):
        if mode in self.obeying_modes and not handing_over:
            return (f'vehicle in {mode} without a hand-over (PX4 returns to OFFBOARD after a disarm there): '
                    'switch to POSCTL or AUTO.LOITER first, arm, then call offboard')
        return None

    def thrust(self, sp: AttitudeSetpoint, config: BridgeConfig, vertical_velocity_mps=0.0):
        """T = hover_throttle * f / g, clipped to [0, 1]."""
        return min(max(float(config.hover_throttle * sp.specific_force_mps2 / GRAVITY_MPS2), 0.0), 1.0)

    def specific_force(self, thrust, config, quaternion):
        return float(np.clip(thrust, 0.0, 1.0)) * GRAVITY_MPS2 / config.hover_throttle

    def decode_param(self, value, param_type):
        """PX4 sends integer parameters bytewise in the float field (MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE)."""
        if param_type == MAV_PARAM_TYPE_REAL32:
            return float(value)
        return float(struct.unpack('<i', struct.pack('<f', value))[0])

    def _check(self, values, config, adopt):
        problems, notes = [], []
        config = self._hover('MPC_THR_HOVER', values, config, adopt, problems, notes)
        loss_s = values['COM_OF_LOSS_T']
        gap_s = FIRST_RESEND_PERIODS / config.setpoint_rate_hz
        if gap_s >= loss_s:
            problems.append(f'COM_OF_LOSS_T = {loss_s:.2f} s on the vehicle is not above the keep-alive\'s longest '
                            f'gap {gap_s:.2f} s ({FIRST_RESEND_PERIODS} / setpoint_rate_hz = '
                            f'{config.setpoint_rate_hz}): raise either')
        if loss_s < config.setpoint_timeout_s:
            notes.append(f'COM_OF_LOSS_T = {loss_s:.2f} s < setpoint_timeout_s = {config.setpoint_timeout_s} s: '
                         'PX4\'s own offboard-loss failsafe (COM_OBL_RC_ACT) acts before the bridge\'s stale_action')
        return ParamCheck(tuple(problems), tuple(notes), config)

    def _check_external_pose(self, values):
        """EKF2_EV_CTRL bits 0 and 1 (fuse horizontal and vertical position), EKF2_HGT_REF 3 (vision height: the
        barometer drifts indoors), EKF2_GPS_CTRL 0 (no GPS indoors: a GPS check would block arming), and the
        EKF2_EV_DELAY the estimator assumes (the pose's age at the autopilot)."""
        problems, notes = [], []
        ev_ctrl, hgt_ref = int(values['EKF2_EV_CTRL']), int(values['EKF2_HGT_REF'])
        if ev_ctrl & 3 != 3:
            problems.append(f'EKF2_EV_CTRL = {ev_ctrl}: the external pose is not fused as position (set bits 0 '
                            f'and 1: EKF2_EV_CTRL = {ev_ctrl | 3})')
        if hgt_ref != 3:
            problems.append(f'EKF2_HGT_REF = {hgt_ref}: height is not from the external pose (set EKF2_HGT_REF = 3)')
        gps_ctrl = int(values['EKF2_GPS_CTRL'])
        if gps_ctrl:
            notes.append(f'EKF2_GPS_CTRL = {gps_ctrl}: GPS is fused where it is received (indoors: set 0)')
        notes.append(f'EKF2_EV_DELAY = {values["EKF2_EV_DELAY"]:g} ms: the pose\'s age the estimator assumes')
        return tuple(problems), tuple(notes)
