"""mavlink_bridge's parameters without ROS: the table the node declares (defaults from BridgeConfig), the rules
between its values (the fcu_url's form, the geofence box) and the configurations built from them."""

import dataclasses

from quad_bridge.backend import BridgeConfig
from quad_bridge.backends import BACKENDS
from quad_bridge.external_pose import ExternalPoseConfig
from quad_bridge.mavlink_client import MAV_COMP_ID_ONBOARD_COMPUTER, check_fcu_url
from quad_common import contract, mocap_frames
from quad_common.params import Param

NAME = 'mavlink_bridge'      # the node's name
DEFAULTS = BridgeConfig()   # the defaults of the parameters BridgeConfig holds (of the same names)
SPECS = [
    Param('fcu_url', 'udpin:0.0.0.0:14540', 'pymavlink connection: udpin:/udpout:/tcp:HOST:PORT or serial device',
          read_only=True),
    Param('baud', 57600, 'serial baud rate (serial fcu_url only)', min=1200, max=4000000, read_only=True),
    Param('autopilot', 'auto', f'auto (from HEARTBEAT.autopilot) | {" | ".join(BACKENDS)}',
          choices=('auto', *BACKENDS), read_only=True),
    Param('target_system', 0, 'vehicle system id; 0 = the first vehicle heartbeat', min=0, max=255, read_only=True),
    Param('target_component', 1, 'vehicle component id (autopilot)', min=0, max=255, read_only=True),
    Param('source_system', 1, 'our MAVLink system id', min=1, max=255, read_only=True),
    Param('source_component', MAV_COMP_ID_ONBOARD_COMPUTER, 'our MAVLink component id (191 = onboard computer)',
          min=1, max=255, read_only=True),
    Param('setpoint_rate_hz', DEFAULTS.setpoint_rate_hz,
          'keep-alive rate: the newest setpoint is re-sent when none went out for a period',
          min=2.0, max=1000.0, read_only=True),
    Param('setpoint_timeout_s', DEFAULTS.setpoint_timeout_s,
          'nothing on the wire for this long: the stream is stale, stale_action',
          min=0.02, max=10.0, read_only=True),
    Param('stale_action', 'land', 'what a stale stream commands: land | hold (ArduPilot always lands)',
          choices=('land', 'hold')),
    Param('link_timeout_s', 2.0, 'nothing from the vehicle for this long (as the receive thread read it): link lost',
          min=0.2, max=30.0),
    Param('hover_throttle', DEFAULTS.hover_throttle,
          'normalised thrust that hovers the vehicle (PX4 MPC_THR_HOVER, ArduPilot MOT_THST_HOVER)',
          min=0.05, max=0.95, read_only=True),
    Param('hover_throttle_tolerance', DEFAULTS.hover_throttle_tolerance,
          'largest |vehicle hover thrust - hover_throttle| offboard accepts',
          min=0.0, max=0.5, read_only=True),
    Param('vehicle_params', 'check',
          'check: refuse offboard when the vehicle\'s parameters contradict ours | adopt: fly with the vehicle\'s '
          '| ignore: do not read them', choices=('check', 'adopt', 'ignore'), read_only=True),
    Param('max_tilt_deg', 35.0, 'setpoints tilted further are clamped to this keeping their vertical acceleration',
          min=1.0, max=85.0),
    Param('ardupilot_thrust_mode', DEFAULTS.ardupilot_thrust_mode,
          'thrust (GUID_OPTIONS bit 3 set) | climb_rate (bit 3 clear)',
          choices=('thrust', 'climb_rate'), read_only=True),
    Param('ardupilot_speed_up_mps', DEFAULTS.ardupilot_speed_up_mps,
          'WPNAV_SPEED_UP: climb rate at thrust 1 (climb_rate mode)', min=0.1, max=20.0,
          read_only=True),
    Param('ardupilot_speed_down_mps', DEFAULTS.ardupilot_speed_down_mps,
          'WPNAV_SPEED_DN: descent rate at thrust 0 (climb_rate mode)',
          min=0.1, max=20.0, read_only=True),
    Param('climb_rate_lead_s', DEFAULTS.climb_rate_lead_s,
          'climb_rate mode: v_z command = v_z + lead * (f cos(tilt) - g)', min=0.01, max=5.0,
          read_only=True),
    Param('telemetry_rate_hz', 50.0, 'rate requested with MAV_CMD_SET_MESSAGE_INTERVAL for odometry/IMU',
          min=1.0, max=500.0, read_only=True),
    Param('stream_grace_s', 3.0, 'a requested telemetry message not seen for this long: fall back, then warn',
          min=0.5, max=30.0, read_only=True),
    Param('command_timeout_s', 3.0, 'how long a service waits for COMMAND_ACK (and PARAM_VALUE)', min=0.1, max=30.0),
    Param('geofence_enabled', False, 'brake before the box geofence_min_m..geofence_max_m (ENU) and land inside it'),
    Param('geofence_min_m', [-50.0, -50.0, -1.0], 'geofence box lower corner (map, ENU)', length=3),
    Param('geofence_max_m', [50.0, 50.0, 30.0], 'geofence box upper corner (map, ENU)', length=3),
    Param('geofence_reaction_s', 0.3, 'geofence: odometry to braking attitude (stopping distance |v| t + |v|^2 / 2a, '
          'a = g tan(max_tilt_deg))', min=0.0, max=2.0, read_only=True),
    Param('signing_key_file', '', 'MAVLink 2 signing key file (64 hex chars or a passphrase); empty = unsigned',
          read_only=True),
    Param('setpoint_source', 'position_controller',
          'the only node whose cmd/attitude_thrust is flown (relative: in the bridge\'s namespace); empty = any '
          'publisher of the domain', read_only=True),
    Param('realtime_priority', 0,
          'every thread of the bridge under SCHED_FIFO at this priority (1..99); 0 = off (the ordinary scheduler)',
          min=0, max=99, read_only=True),
    Param('external_pose_enabled', False,
          f'forward {contract.EXTERNAL_POSE} / {contract.EXTERNAL_ODOM} to the autopilot\'s estimator (motion '
          'capture); its faults end a hand-over', read_only=True),
    Param('external_pose_frame', 'enu', 'frame of the external pose: enu (ENU world, FLU body) | y_up (motion '
          'capture Y-up: (x, y, z) -> (x, -z, y) ENU)', choices=mocap_frames.FRAMES, read_only=True),
    Param('external_pose_rate_hz', 30.0, 'external pose forwarded at most at this rate (PX4 EKF2: 30-50 Hz)',
          min=1.0, max=200.0, read_only=True),
    Param('external_pose_timeout_s', 0.5, 'no timely external pose (none, or only late ones) for this long: fault '
          '(timeout), a hand-over ends', min=0.02, max=10.0, read_only=True),
    Param('external_pose_max_age_s', 0.2, 'an external pose older than this (stamp to arrival): fault (late), '
          'dropped', min=0.005, max=5.0, read_only=True),
    Param('external_pose_max_speed_mps', 10.0, 'a position step beyond speed x dt + external_pose_jump_margin_m '
          'between samples: fault (jump)', min=0.1, max=100.0, read_only=True),
    Param('external_pose_jump_margin_m', 0.1, 'see external_pose_max_speed_mps', min=0.0, max=10.0, read_only=True),
]


def validate(values):
    """The rules between values: fcu_url's form, geofence_min_m below geofence_max_m on every axis."""
    reason = check_fcu_url(values['fcu_url'])
    if reason:
        raise ValueError(reason)
    if any(lo >= hi for lo, hi in zip(values['geofence_min_m'], values['geofence_max_m'])):
        raise ValueError(f'geofence_min_m = {values["geofence_min_m"]} must be below geofence_max_m = '
                         f'{values["geofence_max_m"]} on every axis')


def bridge_config(values) -> BridgeConfig:
    """The BridgeConfig of the parameter values (a mapping by name): its fields are the parameters of their names."""
    return BridgeConfig(**{f.name: values[f.name] for f in dataclasses.fields(BridgeConfig) if f.name in values})


def external_pose_config(values) -> ExternalPoseConfig:
    """The external pose filter's configuration from the external_pose_* parameter values."""
    return ExternalPoseConfig(
        frame=values['external_pose_frame'], max_rate_hz=values['external_pose_rate_hz'],
        timeout_s=values['external_pose_timeout_s'], max_age_s=values['external_pose_max_age_s'],
        max_speed_m_s=values['external_pose_max_speed_mps'], jump_margin_m=values['external_pose_jump_margin_m'])
