"""ROS message <-> numpy conversions shared by every node (the only place they are written).

Contract: quad_common.contract and docs/interfaces.md.
"""

import math

import numpy as np
from builtin_interfaces.msg import Duration, Time
from geometry_msgs.msg import Quaternion, Transform, TransformStamped, Twist, Vector3
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Imu
from trajectory_msgs.msg import MultiDOFJointTrajectory, MultiDOFJointTrajectoryPoint

from quad_common import rotations
from quad_common.contract import BODY_FRAME, UNSET_COVARIANCE, WORLD_FRAME  # noqa: F401  (re-exported)
from quad_common.sampled_trajectory import SampledTrajectory
from quad_common.types import AttitudeSetpoint, Reference, State, all_finite


def stamp_to_s(stamp) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


def ns_to_s(stamp_ns: int) -> float:
    """A stamp in integer nanoseconds (quad_common.ros.cdr's decoders) as stamp_to_s gives it, to the last bit."""
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    return sec + nanosec * 1e-9


def s_to_stamp(t_s: float) -> Time:
    ns = int(round(t_s * 1e9))
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def s_to_duration(t_s: float) -> Duration:
    ns = int(round(t_s * 1e9))
    return Duration(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def vec3(msg) -> np.ndarray:
    return np.array([msg.x, msg.y, msg.z])


def to_vector3(v) -> Vector3:
    return Vector3(x=float(v[0]), y=float(v[1]), z=float(v[2]))


def quat(msg) -> np.ndarray:
    return np.array([msg.x, msg.y, msg.z, msg.w])


def to_quaternion(q) -> Quaternion:
    return Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))


# --- odometry -------------------------------------------------------------------------------

def state_to_odometry(state: State, stamp: Time, frame_id=WORLD_FRAME, child_frame_id=BODY_FRAME) -> Odometry:
    """Twist is expressed in child_frame_id (REP-105): v_body = R^T v_world."""
    msg = Odometry()
    msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    msg.child_frame_id = child_frame_id
    msg.pose.pose.position.x, msg.pose.pose.position.y, msg.pose.pose.position.z = map(float, state.position)
    msg.pose.pose.orientation = to_quaternion(state.quaternion)
    msg.twist.twist = Twist(linear=to_vector3(body_velocity(state)), angular=to_vector3(state.body_rates))
    return msg


def body_velocity(state: State) -> np.ndarray:
    """The odometry twist's linear part: v_body = R^T v_world."""
    return np.array(rotations.rotate_back(state.quaternion.tolist(), state.velocity.tolist()))


def odometry_to_state(msg: Odometry) -> State:
    """Inverse of state_to_odometry: the body-frame twist is rotated back into the world frame."""
    p = msg.pose.pose.position
    return odometry_values_to_state((p.x, p.y, p.z), quat(msg.pose.pose.orientation), vec3(msg.twist.twist.linear),
                                    vec3(msg.twist.twist.angular))


def odometry_values_to_state(position, quaternion, v_body, body_rates) -> State:
    """odometry_to_state on the fields' values (also what quad_common.ros.cdr decodes)."""
    q = rotations.normalize(quaternion)
    return State(position=np.array(position, dtype=float), velocity=np.array(rotations.rotate(q.tolist(), v_body)),
                 quaternion=q, body_rates=np.array(body_rates, dtype=float))


# --- attitude/thrust setpoint (sensor_msgs/Imu used as a setpoint) ---------------------------

def setpoint_to_imu(sp: AttitudeSetpoint, stamp: Time, frame_id=BODY_FRAME) -> Imu:
    msg = Imu()
    msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    msg.orientation = to_quaternion(sp.quaternion)
    msg.linear_acceleration = Vector3(x=0.0, y=0.0, z=float(sp.specific_force_mps2))
    if sp.body_rates is None:
        msg.angular_velocity_covariance[0] = UNSET_COVARIANCE
    else:
        msg.angular_velocity = to_vector3(sp.body_rates)
    return msg


def imu_to_setpoint(msg: Imu) -> AttitudeSetpoint:
    """Raises ValueError on a non-finite or zero quaternion or thrust, naming the field."""
    return imu_values_to_setpoint(quat(msg.orientation), msg.orientation_covariance[0], vec3(msg.angular_velocity),
                                  msg.angular_velocity_covariance[0], msg.linear_acceleration.z,
                                  msg.linear_acceleration_covariance[0])


def imu_values_to_setpoint(orientation, orientation_cov0, rates, rates_cov0, specific_force_mps2,
                           specific_force_cov0) -> AttitudeSetpoint:
    """imu_to_setpoint on the fields' values (also what quad_common.ros.cdr decodes); *_cov0: covariance[0]."""
    if orientation_cov0 == UNSET_COVARIANCE:
        raise ValueError('cmd/attitude_thrust.orientation is marked unset (covariance[0] = -1)')
    if specific_force_cov0 == UNSET_COVARIANCE:
        raise ValueError('cmd/attitude_thrust.linear_acceleration is marked unset (covariance[0] = -1)')
    f = specific_force_mps2
    if not math.isfinite(f):
        raise ValueError(f'cmd/attitude_thrust.linear_acceleration.z must be finite, got {f}')
    try:
        q = rotations.normalize(orientation)
    except ValueError as exc:
        raise ValueError(f'cmd/attitude_thrust.orientation: {exc}') from None
    body_rates = None
    if rates_cov0 != UNSET_COVARIANCE:
        body_rates = np.array(rates, dtype=float)
        if not all_finite((body_rates,)):
            raise ValueError(f'cmd/attitude_thrust.angular_velocity must be finite, got {body_rates.tolist()}')
    return AttitudeSetpoint(quaternion=q, specific_force_mps2=float(f), body_rates=body_rates)


# --- trajectories ---------------------------------------------------------------------------

def _point(t_s, p, v, a) -> MultiDOFJointTrajectoryPoint:
    """p, v, a are (x, y, z, yaw) values and their derivatives."""
    p, v, a = (np.asarray(x, dtype=float).tolist() for x in (p, v, a))  # Python floats: cheap field checks
    return MultiDOFJointTrajectoryPoint(
        transforms=[Transform(translation=Vector3(x=p[0], y=p[1], z=p[2]),
                              rotation=to_quaternion(rotations.from_yaw(p[3]).tolist()))],
        velocities=[Twist(linear=Vector3(x=v[0], y=v[1], z=v[2]), angular=Vector3(z=v[3]))],
        accelerations=[Twist(linear=Vector3(x=a[0], y=a[1], z=a[2]), angular=Vector3(z=a[3]))],
        time_from_start=s_to_duration(t_s))


def sampled_to_msg(traj: SampledTrajectory, start_stamp: Time, frame_id=WORLD_FRAME) -> MultiDOFJointTrajectory:
    msg = MultiDOFJointTrajectory()
    msg.header.stamp = start_stamp
    msg.header.frame_id = frame_id
    msg.joint_names = [BODY_FRAME]
    msg.points = [_point(t, p, v, a) for t, p, v, a in
                  zip(traj.times_s - traj.times_s[0], traj.position, traj.velocity, traj.acceleration)]
    return msg


def msg_to_sampled(msg: MultiDOFJointTrajectory) -> tuple[float, SampledTrajectory]:
    """(start time in seconds from header.stamp, interpolant over time since start)."""
    if not msg.points:
        raise ValueError('trajectory has no points')
    n = len(msg.points)
    t = np.empty(n)
    p, v, a = np.zeros((n, 4)), np.zeros((n, 4)), np.zeros((n, 4))
    q = np.empty((n, 4))
    for k, pt in enumerate(msg.points):
        if not pt.transforms:
            raise ValueError(f'trajectory point {k} has no transform')
        t[k] = pt.time_from_start.sec + pt.time_from_start.nanosec * 1e-9
        tf = pt.transforms[0]
        p[k, :3] = vec3(tf.translation)
        q[k] = quat(tf.rotation)
        if pt.velocities:
            v[k, :3] = vec3(pt.velocities[0].linear)
            v[k, 3] = pt.velocities[0].angular.z
        if pt.accelerations:
            a[k, :3] = vec3(pt.accelerations[0].linear)
            a[k, 3] = pt.accelerations[0].angular.z
    p[:, 3] = rotations.to_euler(q)[:, 2]   # one call for every point's yaw (per point it was most of the time)
    return stamp_to_s(msg.header.stamp), SampledTrajectory(t, p, v, a)


def reference_to_msg(ref: Reference, stamp: Time, frame_id=WORLD_FRAME) -> MultiDOFJointTrajectory:
    """One-point trajectory: what the controller tracked at one tick (`control/reference`)."""
    msg = MultiDOFJointTrajectory()
    msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    msg.joint_names = [BODY_FRAME]
    msg.points = [_point(0.0, [*ref.position, ref.yaw], [*ref.velocity, ref.yaw_rate], [*ref.acceleration, 0.0])]
    return msg


# --- simulated sensors (sim_node, mavlink_vehicle) ---------------------------------------------

def state_to_transform(state: State, stamp: Time, frame_id=WORLD_FRAME, child_frame_id=BODY_FRAME):
    """geometry_msgs/TransformStamped map -> base_link of the state's pose (for /tf)."""
    msg = TransformStamped()
    msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    msg.child_frame_id = child_frame_id
    msg.transform = Transform(translation=to_vector3(state.position), rotation=to_quaternion(state.quaternion))
    return msg


def state_to_imu(state: State, specific_force_body_mps2, stamp: Time, frame_id=BODY_FRAME) -> Imu:
    """A measured IMU reading: attitude, body rates (FLU) and the real specific force R^T (a + g e3)."""
    msg = Imu()
    msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    msg.orientation = to_quaternion(state.quaternion)
    msg.angular_velocity = to_vector3(state.body_rates)
    msg.linear_acceleration = to_vector3(specific_force_body_mps2)
    return msg
