"""The emulator's own reading of the MAVLink protocol as PX4 and ArduPilot Copter speak it.

Written from the MAVLink common.xml definitions and from the autopilots' source and documentation, not
from quad_bridge: the bridge's tests compare two independent readings. Every entry names where it comes
from (paths inside PX4/PX4-Autopilot and ArduPilot/ardupilot, or the documentation page).
"""

# --- MAVLink common.xml enums (mavlink/message_definitions/v1.0/common.xml) ---------------------------
MAV_TYPE_QUADROTOR = 2                       # MAV_TYPE
MAV_AUTOPILOT_ARDUPILOTMEGA = 3              # MAV_AUTOPILOT
MAV_AUTOPILOT_PX4 = 12                       # MAV_AUTOPILOT
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1        # MAV_MODE_FLAG bit 0
MAV_MODE_FLAG_STABILIZE_ENABLED = 16         # MAV_MODE_FLAG bit 4
MAV_MODE_FLAG_GUIDED_ENABLED = 8             # MAV_MODE_FLAG bit 3
MAV_MODE_FLAG_SAFETY_ARMED = 128             # MAV_MODE_FLAG bit 7
MAV_STATE_STANDBY = 3                        # MAV_STATE
MAV_STATE_ACTIVE = 4                         # MAV_STATE

MAV_RESULT_ACCEPTED = 0                      # MAV_RESULT
MAV_RESULT_TEMPORARILY_REJECTED = 1
MAV_RESULT_DENIED = 2
MAV_RESULT_UNSUPPORTED = 3
MAV_RESULT_FAILED = 4

MAV_CMD_NAV_LAND = 21                        # MAV_CMD
MAV_CMD_DO_SET_MODE = 176
MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_CMD_REQUEST_MESSAGE = 512
ARM_DISARM_FORCE_MAGIC = 21196               # MAV_CMD_COMPONENT_ARM_DISARM param2: force (both autopilots)

# SET_ATTITUDE_TARGET.type_mask (ATTITUDE_TARGET_TYPEMASK)
TYPEMASK_BODY_ROLL_RATE_IGNORE = 1
TYPEMASK_BODY_PITCH_RATE_IGNORE = 2
TYPEMASK_BODY_YAW_RATE_IGNORE = 4
TYPEMASK_THRUST_BODY_SET = 32                # thrust_body field used instead of thrust (PX4 only)
TYPEMASK_THROTTLE_IGNORE = 64
TYPEMASK_ATTITUDE_IGNORE = 128
TYPEMASK_RATES_IGNORE = (TYPEMASK_BODY_ROLL_RATE_IGNORE | TYPEMASK_BODY_PITCH_RATE_IGNORE
                         | TYPEMASK_BODY_YAW_RATE_IGNORE)

# SYS_STATUS onboard_control_sensors_* bits (MAV_SYS_STATUS_SENSOR)
MAV_SYS_STATUS_SENSOR_3D_GYRO = 0x1
MAV_SYS_STATUS_SENSOR_3D_ACCEL = 0x2
MAV_SYS_STATUS_SENSOR_3D_MAG = 0x4
MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE = 0x8
MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL = 0x400
MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION = 0x800
MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS = 0x8000
MAV_SYS_STATUS_AHRS = 0x200000
MAV_SYS_STATUS_PREARM_CHECK = 0x10000000     # bit 28
MAV_SYS_STATUS_EXTENSION_USED = 0x80000000   # bit 31
SENSORS_BASIC = (MAV_SYS_STATUS_SENSOR_3D_GYRO | MAV_SYS_STATUS_SENSOR_3D_ACCEL | MAV_SYS_STATUS_SENSOR_3D_MAG
                 | MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE | MAV_SYS_STATUS_AHRS)

# MAV_PARAM_TYPE
MAV_PARAM_TYPE_INT8 = 2
MAV_PARAM_TYPE_INT16 = 4
MAV_PARAM_TYPE_INT32 = 6
MAV_PARAM_TYPE_REAL32 = 9

# MAV_DATA_STREAM (REQUEST_DATA_STREAM.req_stream_id)
MAV_DATA_STREAM_ALL = 0
MAV_DATA_STREAM_RAW_SENSORS = 1
MAV_DATA_STREAM_EXTENDED_STATUS = 2
MAV_DATA_STREAM_RC_CHANNELS = 3
MAV_DATA_STREAM_POSITION = 6
MAV_DATA_STREAM_EXTRA1 = 10
MAV_DATA_STREAM_EXTRA2 = 11
MAV_DATA_STREAM_EXTRA3 = 12

# MAV_FRAME
MAV_FRAME_LOCAL_NED = 1
MAV_FRAME_BODY_FRD = 12
MAV_FRAME_LOCAL_FRD = 20
MAV_ESTIMATOR_TYPE_AUTOPILOT = 1

# --- PX4 -----------------------------------------------------------------------------------------------
# custom_mode = union px4_custom_mode {uint16 reserved; uint8 main_mode; uint8 sub_mode}, little endian:
# main mode in bits 16-23, sub mode in bits 24-31 (src/modules/commander/px4_custom_mode.h).
PX4_MAIN_MODES = {  # enum PX4_CUSTOM_MAIN_MODE (px4_custom_mode.h)
    'MANUAL': 1, 'ALTCTL': 2, 'POSCTL': 3, 'AUTO': 4, 'ACRO': 5, 'OFFBOARD': 6, 'STABILIZED': 7,
}
PX4_AUTO_SUB_MODES = {  # enum PX4_CUSTOM_SUB_MODE_AUTO (px4_custom_mode.h)
    'READY': 1, 'TAKEOFF': 2, 'LOITER': 3, 'MISSION': 4, 'RTL': 5, 'LAND': 6, 'FOLLOW_TARGET': 8, 'PRECLAND': 9,
}
# Modes that set mode_req_prevent_arming (src/modules/commander/ModeUtil/mode_requirements.cpp): a vehicle
# cannot be armed in them, and UserModeIntention::change() does not store them as the mode to return to after
# disarming (src/modules/commander/UserModeIntention.cpp, _nav_state_after_disarming).
PX4_PREVENT_ARMING = frozenset({'AUTO.RTL', 'AUTO.LAND', 'AUTO.PRECLAND', 'AUTO.FOLLOW_TARGET'})
# Modes that need manual control (RC) to run (mode_requirements.cpp: mode_req_manual_control). The emulator has
# no RC, so a failsafe action that selects one falls through to Hold (src/modules/commander/failsafe/
# framework.cpp, getSelectedAction: FallbackPosCtrl -> FallbackAltCtrl -> FallbackStab -> Hold).
PX4_NEEDS_MANUAL_CONTROL = frozenset({'MANUAL', 'ALTCTL', 'POSCTL', 'ACRO', 'STABILIZED'})
# COM_OBL_RC_ACT, "Set offboard loss failsafe mode" (src/modules/commander/commander_params.c / PX4 parameter
# reference): 0 Position, 1 Altitude, 2 Manual, 3 Return, 4 Land, 5 Hold, 6 Terminate, 7 Disarm.
PX4_OFFBOARD_LOSS_ACTIONS = {0: 'POSCTL', 1: 'ALTCTL', 2: 'STABILIZED', 3: 'AUTO.RTL', 4: 'AUTO.LAND',
                             5: 'AUTO.LOITER', 6: 'TERMINATE', 7: 'DISARM'}
# "The vehicle must be receiving a stream of setpoints before arming in offboard mode or switching to offboard
# mode when flying ... at > 2 Hz" (PX4 user guide, flight_modes/offboard.md). The commander's own check
# (HealthAndArmingChecks/checks/offboardCheck.cpp) is: last offboard_control_mode younger than COM_OF_LOSS_T.
PX4_OFFBOARD_MIN_RATE_HZ = 2.0
# Streams an onboard-mode MAVLink instance sends unasked (src/modules/mavlink/mavlink_main.cpp,
# configure_streams_to_default, case MAVLINK_MODE_ONBOARD; SITL starts port 14540 with -m onboard).
PX4_ONBOARD_DEFAULT_RATES_HZ = {
    'HEARTBEAT': 1.0, 'TIMESYNC': 10.0, 'HIGHRES_IMU': 50.0, 'LOCAL_POSITION_NED': 30.0, 'ATTITUDE': 100.0,
    'ODOMETRY': 30.0, 'ATTITUDE_QUATERNION': 50.0, 'BATTERY_STATUS': 0.5, 'SYS_STATUS': 1.0,
}
# Messages the emulated PX4 can stream (a subset of src/modules/mavlink/streams/).
PX4_STREAMABLE = frozenset({'HEARTBEAT', 'TIMESYNC', 'HIGHRES_IMU', 'LOCAL_POSITION_NED', 'ATTITUDE', 'ODOMETRY',
                            'ATTITUDE_QUATERNION', 'BATTERY_STATUS', 'SYS_STATUS', 'SCALED_IMU'})


def px4_custom_mode(name: str) -> int:
    """HEARTBEAT.custom_mode of a PX4 mode name ('OFFBOARD', 'AUTO.LOITER')."""
    main, _, sub = name.partition('.')
    return PX4_MAIN_MODES[main] << 16 | (PX4_AUTO_SUB_MODES[sub] if sub else 0) << 24


def px4_mode_name(main_mode: int, sub_mode: int) -> str | None:
    """Mode name of MAV_CMD_DO_SET_MODE(param2 = main, param3 = sub); None when PX4 has no such mode."""
    mains = {v: k for k, v in PX4_MAIN_MODES.items()}
    subs = {v: k for k, v in PX4_AUTO_SUB_MODES.items()}
    main = mains.get(int(main_mode))
    if main is None:
        return None
    if main != 'AUTO':
        return main
    sub = subs.get(int(sub_mode))
    return f'AUTO.{sub}' if sub else None


# --- ArduPilot Copter ----------------------------------------------------------------------------------
# HEARTBEAT.custom_mode is Mode::Number (ArduCopter/mode.h); MAV_CMD_DO_SET_MODE takes it in param2.
PX4_VISUAL_ODOMETRY_ESTIMATORS = frozenset({2, 3})   # MAV_ESTIMATOR_TYPE_VISION, _VIO

COPTER_MODES = {
    'STABILIZE': 0, 'ACRO': 1, 'ALT_HOLD': 2, 'AUTO': 3, 'GUIDED': 4, 'LOITER': 5, 'RTL': 6, 'CIRCLE': 7,
    'LAND': 9, 'DRIFT': 11, 'SPORT': 13, 'FLIP': 14, 'AUTOTUNE': 15, 'POSHOLD': 16, 'BRAKE': 17, 'THROW': 18,
    'AVOID_ADSB': 19, 'GUIDED_NOGPS': 20, 'SMART_RTL': 21, 'FLOWHOLD': 22, 'FOLLOW': 23, 'ZIGZAG': 24,
}
# ModeGuided::in_guided_mode() is true for GUIDED and its subclass GUIDED_NOGPS (mode.h); only then is
# SET_ATTITUDE_TARGET used (ArduCopter/GCS_Mavlink.cpp, handle_message_set_attitude_target).
COPTER_GUIDED_MODES = frozenset({'GUIDED', 'GUIDED_NOGPS'})
# Modes whose allows_arming() is false (mode.h: ModeLand, ModeRTL, ModeSmartRTL, ModeAuto without AUTO_OPTIONS).
COPTER_NO_ARMING = frozenset({'LAND', 'RTL', 'SMART_RTL', 'AUTO', 'BRAKE', 'CIRCLE', 'FLIP', 'AUTOTUNE'})
# GUID_OPTIONS bit 3 "SetAttitudeTarget_ThrustAsThrust" (ArduCopter/mode.h, ModeGuided::Option).
GUID_OPTIONS_THRUST_AS_THRUST = 1 << 3
# ATC_ANGLE_BOOST: throttle / cos(tilt), the tilt clamped to cos >= 0.1 (libraries/AC_AttitudeControl/
# AC_AttitudeControl_Multi.cpp, get_throttle_boosted).
ANGLE_BOOST_MIN_COS = 0.1
# Position controller defaults (libraries/AC_AttitudeControl/AC_PosControl.cpp): PSC_POSZ_P 1.0 1/s, PSC_VELZ_P
# 5.0 1/s; the vertical loop that turns GUIDED's climb rate (and the GUID_TIMEOUT level hold) into thrust.
PSC_POSZ_P = 1.0
PSC_VELZ_P = 5.0
# REQUEST_DATA_STREAM groups (ArduCopter/GCS_Mavlink.cpp, STREAM_*_msgs), restricted to what the emulator sends.
COPTER_DATA_STREAMS = {
    MAV_DATA_STREAM_RAW_SENSORS: ('RAW_IMU', 'SCALED_IMU2', 'SCALED_PRESSURE'),
    MAV_DATA_STREAM_EXTENDED_STATUS: ('SYS_STATUS', 'POWER_STATUS', 'MEMINFO'),
    MAV_DATA_STREAM_POSITION: ('GLOBAL_POSITION_INT', 'LOCAL_POSITION_NED'),
    MAV_DATA_STREAM_EXTRA1: ('ATTITUDE', 'AHRS2'),
    MAV_DATA_STREAM_EXTRA2: ('VFR_HUD',),
    MAV_DATA_STREAM_EXTRA3: ('SYSTEM_TIME', 'BATTERY_STATUS', 'VIBRATION'),
}
# MAVLink ids with an ap_message (libraries/GCS_MAVLink/GCS_Common.cpp, mavlink_id_to_ap_message_id), restricted
# to what the emulator sends. HIGHRES_IMU (105) and ODOMETRY (331) are not among them: SET_MESSAGE_INTERVAL for
# them fails with STATUSTEXT "No ap_message for mavlink id (105)".
COPTER_STREAMABLE = frozenset({'HEARTBEAT', 'ATTITUDE', 'ATTITUDE_QUATERNION', 'GLOBAL_POSITION_INT', 'SYS_STATUS',
                               'POWER_STATUS', 'MEMINFO', 'VFR_HUD', 'RAW_IMU', 'SCALED_IMU', 'SCALED_IMU2',
                               'SCALED_PRESSURE', 'SYSTEM_TIME', 'AHRS2', 'LOCAL_POSITION_NED', 'VIBRATION',
                               'BATTERY_STATUS'})
# Only the heartbeat goes out before anything is requested: SITL's SRn_* stream rates are 0 unless a GCS asks
# (REQUEST_DATA_STREAM or MAV_CMD_SET_MESSAGE_INTERVAL); GCS_Common.cpp sends HEARTBEAT at 1 Hz regardless.
COPTER_DEFAULT_RATES_HZ = {'HEARTBEAT': 1.0}
