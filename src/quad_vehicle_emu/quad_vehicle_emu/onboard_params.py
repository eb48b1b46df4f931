"""Onboard parameters the emulator answers for (PARAM_REQUEST_READ / _LIST / PARAM_SET), and how each autopilot
puts a value into PARAM_VALUE.param_value.

ArduPilot sends every type as the float of its value (libraries/GCS_MAVLink/GCS_Param.cpp, send_parameter_value
with vp->cast_to_float). PX4 copies integer bits into the float field (MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE,
src/modules/mavlink/mavlink_parameters.cpp, send_param: memcpy of the int32).
"""

import math
import struct
from dataclasses import dataclass

from quad_vehicle_emu import protocol as p


@dataclass(frozen=True)
class ParamSpec:
    name: str
    default: float
    mav_type: int
    low: float
    high: float
    source: str


ARDUCOPTER_PARAMS = [
    ParamSpec('GUID_OPTIONS', 0, p.MAV_PARAM_TYPE_INT32, 0, 2 ** 31 - 1,
              'ArduCopter/Parameters.cpp (g2.guided_options), default 0: thrust field = climb rate'),
    ParamSpec('GUID_TIMEOUT', 3.0, p.MAV_PARAM_TYPE_REAL32, 0.1, 5.0,
              'ArduCopter/Parameters.cpp (g2.guided_timeout), s, default 3'),
    ParamSpec('MOT_THST_HOVER', 0.35, p.MAV_PARAM_TYPE_REAL32, 0.125, 0.6875,
              'libraries/AP_Motors/AP_MotorsMulticopter.cpp, learnt hover throttle (MOT_HOVER_LEARN 2)'),
    ParamSpec('ATC_ANGLE_BOOST', 1, p.MAV_PARAM_TYPE_INT8, 0, 1,
              'libraries/AC_AttitudeControl/AC_AttitudeControl_Multi.cpp, default 1 (enabled)'),
    ParamSpec('ATC_INPUT_TC', 0.15, p.MAV_PARAM_TYPE_REAL32, 0.0, 1.0,
              'libraries/AC_AttitudeControl/AC_AttitudeControl.cpp, attitude input time constant, s'),
    ParamSpec('WPNAV_SPEED_UP', 250.0, p.MAV_PARAM_TYPE_REAL32, 10.0, 1000.0,
              'libraries/AC_WPNav/AC_WPNav.cpp, cm/s, default 250'),
    ParamSpec('WPNAV_SPEED_DN', 150.0, p.MAV_PARAM_TYPE_REAL32, 10.0, 500.0,
              'libraries/AC_WPNav/AC_WPNav.cpp, cm/s, default 150'),
    ParamSpec('LAND_SPEED', 50.0, p.MAV_PARAM_TYPE_INT16, 30.0, 200.0,
              'ArduCopter/Parameters.cpp, final descent cm/s, default 50'),
    ParamSpec('SYSID_THISMAV', 1, p.MAV_PARAM_TYPE_INT16, 1, 255, 'ArduCopter/Parameters.cpp, default 1'),
    ParamSpec('VISO_TYPE', 0, p.MAV_PARAM_TYPE_INT8, 0, 3,
              'libraries/AP_VisualOdom/AP_VisualOdom.cpp, default 0 (none); 1 MAVLink'),
    ParamSpec('VISO_DELAY_MS', 10, p.MAV_PARAM_TYPE_INT16, 0, 250,
              'libraries/AP_VisualOdom/AP_VisualOdom.cpp, sensor delay ms, default 10'),
    ParamSpec('EK3_SRC1_POSXY', 3, p.MAV_PARAM_TYPE_INT8, 0, 7,
              'libraries/AP_NavEKF/AP_NavEKF_Source.cpp, default 3 (GPS); 6 ExternalNAV'),
    ParamSpec('EK3_SRC1_VELXY', 3, p.MAV_PARAM_TYPE_INT8, 0, 7,
              'libraries/AP_NavEKF/AP_NavEKF_Source.cpp, default 3 (GPS); 6 ExternalNAV'),
    ParamSpec('EK3_SRC1_POSZ', 1, p.MAV_PARAM_TYPE_INT8, 0, 7,
              'libraries/AP_NavEKF/AP_NavEKF_Source.cpp, default 1 (Baro); 6 ExternalNAV'),
    ParamSpec('EK3_SRC1_VELZ', 3, p.MAV_PARAM_TYPE_INT8, 0, 7,
              'libraries/AP_NavEKF/AP_NavEKF_Source.cpp, default 3 (GPS); 6 ExternalNAV'),
    ParamSpec('EK3_SRC1_YAW', 1, p.MAV_PARAM_TYPE_INT8, 0, 8,
              'libraries/AP_NavEKF/AP_NavEKF_Source.cpp, default 1 (Compass); 6 ExternalNAV'),
]

PX4_PARAMS = [
    ParamSpec('MPC_THR_HOVER', 0.5, p.MAV_PARAM_TYPE_REAL32, 0.1, 0.8,
              'src/modules/mc_pos_control/multicopter_position_control_params.c, default 0.5'),
    ParamSpec('COM_OF_LOSS_T', 1.0, p.MAV_PARAM_TYPE_REAL32, 0.0, 60.0,
              'src/modules/commander/commander_params.c, offboard loss timeout s, default 1.0'),
    ParamSpec('COM_OBL_RC_ACT', 0, p.MAV_PARAM_TYPE_INT32, 0, 7,
              'src/modules/commander/commander_params.c, offboard loss action, default 0 (Position mode)'),
    ParamSpec('COM_DISARM_LAND', 2.0, p.MAV_PARAM_TYPE_REAL32, -1.0, 20.0,
              'src/modules/commander/commander_params.c, disarm this long after landing, s, default 2'),
    ParamSpec('MPC_LAND_SPEED', 0.7, p.MAV_PARAM_TYPE_REAL32, 0.6, 10.0,
              'src/modules/mc_pos_control/multicopter_position_control_params.c, m/s, default 0.7'),
    ParamSpec('MC_ROLL_P', 6.5, p.MAV_PARAM_TYPE_REAL32, 0.0, 12.0,
              'src/modules/mc_att_control/mc_att_control_params.c, roll angle P 1/s, default 6.5'),
    ParamSpec('MAV_SYS_ID', 1, p.MAV_PARAM_TYPE_INT32, 1, 250, 'src/modules/mavlink/mavlink_params.c'),
    ParamSpec('EKF2_EV_CTRL', 15, p.MAV_PARAM_TYPE_INT32, 0, 15,
              'src/modules/ekf2/module.yaml, external vision aiding bitmask (0 hor. pos, 1 vert. pos, 2 vel, 3 yaw), '
              'default 15'),
    ParamSpec('EKF2_HGT_REF', 1, p.MAV_PARAM_TYPE_INT32, 0, 3,
              'src/modules/ekf2/module.yaml, height reference 0 baro 1 GPS 2 range 3 vision, default 1'),
    ParamSpec('EKF2_EV_DELAY', 0.0, p.MAV_PARAM_TYPE_REAL32, 0.0, 300.0,
              'src/modules/ekf2/module.yaml, vision measurement delay ms, default 0'),
    ParamSpec('EKF2_GPS_CTRL', 7, p.MAV_PARAM_TYPE_INT32, 0, 15,
              'src/modules/ekf2/module.yaml, GNSS aiding bitmask (0 lon/lat, 1 alt, 2 3D vel, 3 heading), default 7'),
]


class ParameterStore:
    """Name -> value with the autopilot's PARAM_VALUE encoding; refuses unknown names and out-of-range values."""

    def __init__(self, specs, bytewise_ints: bool):
        self.specs = {s.name: s for s in specs}
        self.order = [s.name for s in specs]
        self.values = {s.name: float(s.default) for s in specs}
        self.bytewise_ints = bytewise_ints

    def __getitem__(self, name):
        return self.values[name]

    def set(self, name: str, value: float):
        """Raises ValueError naming the parameter and the value."""
        spec = self.specs.get(name)
        if spec is None:
            raise ValueError(f'parameter {name!r} unknown to this vehicle (known: {", ".join(self.order)})')
        value = float(value)
        if not math.isfinite(value) or not spec.low <= value <= spec.high:
            raise ValueError(f'parameter {name} = {value!r} out of range [{spec.low}, {spec.high}]')
        if spec.mav_type != p.MAV_PARAM_TYPE_REAL32:
            value = float(round(value))
        self.values[name] = value

    def encode(self, name: str) -> tuple[float, int]:
        """(param_value, param_type) as the autopilot puts them into PARAM_VALUE."""
        spec = self.specs[name]
        value = self.values[name]
        if spec.mav_type != p.MAV_PARAM_TYPE_REAL32 and self.bytewise_ints:
            return struct.unpack('<f', struct.pack('<i', int(value)))[0], spec.mav_type
        return value, spec.mav_type

    def decode(self, name: str, param_value: float, param_type: int) -> float:
        """The value a PARAM_SET carries (bytewise ints for PX4, float cast for ArduPilot)."""
        if self.bytewise_ints and param_type != p.MAV_PARAM_TYPE_REAL32:
            return float(struct.unpack('<i', struct.pack('<f', param_value))[0])
        return float(param_value)

    def index(self, name: str) -> int:
        return self.order.index(name)
