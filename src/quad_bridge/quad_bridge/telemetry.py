"""Telemetry messages -> ROS-frame values and the autopilot's own time of each (no rclpy).

Units per the MAVLink common message set: HIGHRES_IMU m/s^2 and rad/s; SCALED_IMU mG and mrad/s
(ArduPilot sends RAW_IMU in the same units, GCS_Common.cpp send_raw_imu).
"""

import math

import numpy as np

from quad_bridge import frames
from quad_bridge.mavlink_client import mavlink
from quad_common import rotations
from quad_common.types import GRAVITY_MPS2, State

MILLI_G_MPS2 = GRAVITY_MPS2 / 1000.0


def time_us(msg) -> int | None:
    """The autopilot's time of a message in us (time_boot_ms or time_usec), None when it carries none."""
    ms = getattr(msg, 'time_boot_ms', None)
    if ms is not None:
        return int(ms) * 1000
    us = getattr(msg, 'time_usec', None)
    return int(us) if us is not None else None


def state_from_local_position(msg, q_ned, rates_frd) -> State:
    """LOCAL_POSITION_NED + the latest ATTITUDE_QUATERNION -> State in ENU/FLU."""
    return frames.state_from_ned(State(position=np.array([msg.x, msg.y, msg.z]),
                                       velocity=np.array([msg.vx, msg.vy, msg.vz]),
                                       quaternion=q_ned, body_rates=np.asarray(rates_frd, float)))


def attitude_enu(msg) -> tuple:
    """ATTITUDE_QUATERNION -> (quaternion ENU/FLU (x, y, z, w), body rates FLU) as Python floats: the arithmetic
    of frames.from_mavlink_quaternion, quaternion_ned_to_enu and body_flu_frd without their arrays (every
    attitude message goes through here)."""
    w, x, y, z = float(msg.q1), float(msg.q2), float(msg.q3), float(msg.q4)
    sign = -frames.S if -w - z < 0 else frames.S
    return ((sign * (-x - y), sign * (y - x), sign * (z - w), sign * (-w - z)),
            (float(msg.rollspeed), -float(msg.pitchspeed), -float(msg.yawspeed)))


def local_position_enu(msg) -> tuple:
    """LOCAL_POSITION_NED -> (position, velocity) in ENU as Python floats (frames.world_enu_ned's map)."""
    return (float(msg.y), float(msg.x), -float(msg.z)), (float(msg.vy), float(msg.vx), -float(msg.vz))


def finite(*vectors) -> bool:
    return all(map(math.isfinite, sum(vectors, ())))


def imu_flu_floats(msg) -> tuple:
    """imu_flu as Python floats: (specific force m/s^2, body rates rad/s) in FLU."""
    acc = (float(msg.xacc), float(msg.yacc), float(msg.zacc))
    gyro = (float(msg.xgyro), float(msg.ygyro), float(msg.zgyro))
    if msg.get_type() != 'HIGHRES_IMU':
        acc, gyro = tuple(a * MILLI_G_MPS2 for a in acc), tuple(g * 1e-3 for g in gyro)
    return (acc[0], -acc[1], -acc[2]), (gyro[0], -gyro[1], -gyro[2])


def state_from_odometry(msg) -> State | None:
    """ODOMETRY with a NED world frame (velocity in body FRD or in the world frame) -> State in ENU/FLU."""
    if msg.frame_id not in (mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_LOCAL_FRD):
        return None
    q = frames.from_mavlink_quaternion(msg.q)
    vel = np.array([msg.vx, msg.vy, msg.vz])
    if msg.child_frame_id == mavlink.MAV_FRAME_BODY_FRD:
        vel = rotations.to_matrix(q) @ vel
    return frames.state_from_ned(State(position=np.array([msg.x, msg.y, msg.z]), velocity=vel, quaternion=q,
                                       body_rates=np.array([msg.rollspeed, msg.pitchspeed, msg.yawspeed])))


def imu_flu(msg) -> tuple[np.ndarray, np.ndarray]:
    """(specific force m/s^2, body rates rad/s) in FLU from HIGHRES_IMU, SCALED_IMU or RAW_IMU."""
    acc = np.array([msg.xacc, msg.yacc, msg.zacc], float)
    gyro = np.array([msg.xgyro, msg.ygyro, msg.zgyro], float)
    if msg.get_type() != 'HIGHRES_IMU':
        acc, gyro = acc * MILLI_G_MPS2, gyro * 1e-3
    return frames.body_flu_frd(acc), frames.body_flu_frd(gyro)
