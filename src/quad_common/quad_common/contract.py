"""The interface contract between the processes, in one place (docs/interfaces.md): topic names, their message
types and QoS, the diagnostic status names and keys that carry events, and the `cmd/attitude_thrust` encoding.

No rclpy here (the report and the offline tools read it too); `qos(topic)` builds the rclpy profile on demand.
"""

import re
from dataclasses import dataclass

# --- topics (relative names: a namespace prefixes them; /clock and /tf are global) --------------------------
ODOM = 'odom'
TRAJECTORY = 'trajectory'
TRAJECTORY_PATH = 'trajectory/path'
TRAJECTORY_MARKERS = 'trajectory/markers'
TRAJECTORY_WAYPOINTS = 'trajectory/waypoints'
WAYPOINTS = 'waypoints'
SETPOINT = 'cmd/attitude_thrust'
REFERENCE = 'control/reference'
IMU = 'imu'
ROTOR_SPEEDS = 'rotor_speeds'
BATTERY = 'battery'
CLOCK = '/clock'
TF = '/tf'
DIAGNOSTICS = 'diagnostics'
# std_msgs/Bool, latched: true while the vehicle flies our setpoints (bridge: hand-over active; simulator: always)
ENGAGED = 'vehicle/engaged'
# an external pose of the vehicle (motion capture, vision): what the bridge forwards to the autopilot's estimator
# and the controller may fly from; ENU world, FLU body unless the consumer's frame parameter says otherwise
EXTERNAL_POSE = 'external/pose'
EXTERNAL_ODOM = 'external/odometry'


@dataclass(frozen=True)
class Topic:
    """A topic of the contract: its ROS type name, and its QoS (always RELIABLE, KEEP_LAST depth; latched =
    TRANSIENT_LOCAL, so a late subscriber gets the last message)."""
    name: str
    msgtype: str
    latched: bool = False
    depth: int = 10


TOPICS = {t.name: t for t in (
    Topic(TRAJECTORY, 'trajectory_msgs/msg/MultiDOFJointTrajectory', latched=True, depth=1),
    Topic(TRAJECTORY_PATH, 'nav_msgs/msg/Path', latched=True, depth=1),
    Topic(TRAJECTORY_MARKERS, 'visualization_msgs/msg/MarkerArray', latched=True, depth=1),
    Topic(TRAJECTORY_WAYPOINTS, 'nav_msgs/msg/Path', latched=True, depth=1),
    Topic(WAYPOINTS, 'nav_msgs/msg/Path'),
    Topic(ODOM, 'nav_msgs/msg/Odometry'),
    Topic(SETPOINT, 'sensor_msgs/msg/Imu'),
    Topic(REFERENCE, 'trajectory_msgs/msg/MultiDOFJointTrajectory'),
    Topic(IMU, 'sensor_msgs/msg/Imu'),
    Topic(ROTOR_SPEEDS, 'sensor_msgs/msg/JointState'),
    Topic(BATTERY, 'sensor_msgs/msg/BatteryState'),
    Topic(CLOCK, 'rosgraph_msgs/msg/Clock'),
    Topic(TF, 'tf2_msgs/msg/TFMessage', depth=100),
    Topic(DIAGNOSTICS, 'diagnostic_msgs/msg/DiagnosticArray'),
    Topic(ENGAGED, 'std_msgs/msg/Bool', latched=True, depth=1),
    Topic(EXTERNAL_POSE, 'geometry_msgs/msg/PoseStamped'),
    Topic(EXTERNAL_ODOM, 'nav_msgs/msg/Odometry'),
)}


VEHICLE_NAME_RULE = 'a letter then letters, digits or _ (it becomes the vehicle\'s namespace)'


def is_vehicle_name(name) -> bool:
    """A fleet vehicle's name: one ROS namespace component (/cf1/odom), ASCII (VEHICLE_NAME_RULE)."""
    return isinstance(name, str) and re.fullmatch(r'[A-Za-z][A-Za-z0-9_]*', name) is not None


def qos(topic: str, depth: int | None = None):
    """The rclpy QoSProfile of a contract topic (depth: override, e.g. a subscriber that must not drop)."""
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    spec = TOPICS[topic]
    return QoSProfile(depth=depth or spec.depth, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if spec.latched else DurabilityPolicy.VOLATILE)


def matches(topic: str, wanted: str) -> bool:
    """'odom' matches 'odom', '/odom' and '/uav1/odom' (a namespaced graph)."""
    return topic.lstrip('/') == wanted.lstrip('/') or topic.endswith('/' + wanted.lstrip('/'))


def contract_name(topic: str) -> str | None:
    """The contract topic `topic` is: the longest contract name it matches ('/cf1/odom' -> 'odom',
    'trajectory/waypoints' -> itself, not 'waypoints'); None for a topic outside the contract."""
    names = [name for name in TOPICS if matches(topic, name)]
    return max(names, key=len) if names else None


# --- frames and the setpoint encoding (cmd/attitude_thrust: sensor_msgs/Imu used as a setpoint) -----------
WORLD_FRAME = 'map'        # ENU
BODY_FRAME = 'base_link'   # FLU
# orientation = the attitude setpoint (map <- base_link); linear_acceleration.z = the collective specific force
# (thrust / mass, m/s^2) along body z; angular_velocity = body-rate feed-forward (rad/s), unset when
# angular_velocity_covariance[0] == UNSET_COVARIANCE (as REP-145 marks an absent field); an orientation or
# linear_acceleration so marked makes the setpoint invalid. Written by conversions.setpoint_to_imu and
# cdr.SetpointPacker, read by conversions.imu_to_setpoint and cdr.imu_to_setpoint (tested equal).
UNSET_COVARIANCE = -1.0

# --- diagnostics: status names and the keys that carry events ---------------------------------------------
# An event is a key of an ERROR status, never parsed from its message: the value is the event's simulated time
# in seconds, written with repr() (full double precision).
COLLISION_TIME_S = 'collision_time_s'
FAILSAFE_TIME_S = 'failsafe_time_s'
STOP_TIME_S = 'stop_time_s'
SIM_STATUS = 'sim_node: {}'        # .format('collision' | 'failsafe' | 'saturation' | 'stopped' | ...)
SIM_PUBLISHED = SIM_STATUS.format('published')   # steps: distinct odom and /clock steps published
SIM_FAILSAFE = SIM_STATUS.format('failsafe')     # FAILSAFE_TIME_S once the failsafe has landed the vehicle
CONTROLLER_STATUS = 'position_controller: cmd/attitude_thrust'
# the mean age (tick time - odometry stamp, ms) of the odometry the controller flew since its previous report: what
# a vehicle's link delays plus the wait for the next sample and tick, measured where it acts (replay's twin flies it)
CONTROLLER_ODOM_AGE_MS = 'odom_age_ms'
RECORDER_STATUS = 'recorder'       # one value per topic: messages written to the bag


def event_time_s(values: dict, key: str) -> float | None:
    """The event time carried under `key` in a status's key/values (dict), or None when it is not there."""
    value = values.get(key)
    return None if value is None else float(value)
