"""Motion-capture frames -> ROS ENU / FLU (one place: the bridge's external pose and the controller's pose state).

- enu:  world ENU, body FLU (ROS REP 103, what vrpn_mocap and mocap4r2 publish when set up Z-up).
- y_up: motion-capture Y-up (world and rigid body: x forward, y up, z = x cross y); ENU = R_x(+90 deg) Y-up,
  (x, y, z)_Yup -> (x, -z, y)_ENU, and the attitude R_ENU_FLU = R_x R_Yup R_x^T.
"""

import math

import numpy as np

from quad_common import rotations

FRAMES = ('enu', 'y_up')
_Q_ENU_YUP = np.array([math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)])   # +90 deg about x, (x, y, z, w)


def check_frame(frame: str) -> str:
    if frame not in FRAMES:
        raise ValueError(f'external_pose_frame must be one of {", ".join(FRAMES)}, got {frame!r}')
    return frame


def to_enu(frame: str, position, quaternion, velocity=None):
    """(world position, attitude body -> world (x,y,z,w), body velocity or None: nav_msgs/Odometry's twist is in
    its child (body) frame) in `frame` -> world ENU position, attitude FLU -> ENU, body FLU velocity."""
    position = np.asarray(position, dtype=float)
    quaternion = rotations.normalize(quaternion)
    if check_frame(frame) == 'enu':
        return position, quaternion, None if velocity is None else np.asarray(velocity, dtype=float)
    rotate = rotations.to_matrix(_Q_ENU_YUP)
    q = rotations.multiply(rotations.multiply(_Q_ENU_YUP, quaternion), rotations.conjugate(_Q_ENU_YUP))
    return rotate @ position, q, None if velocity is None else rotate @ np.asarray(velocity, dtype=float)


def from_enu(frame: str, position, quaternion):
    """to_enu's inverse for a pose: world ENU position and attitude FLU -> ENU (x,y,z,w) -> the same in `frame`
    (a motion-capture stand-in publishing as a Y-up system would: (x, y, z)_ENU -> (x, z, -y)_Yup)."""
    position = np.asarray(position, dtype=float)
    quaternion = rotations.normalize(quaternion)
    if check_frame(frame) == 'enu':
        return position, quaternion
    back = rotations.conjugate(_Q_ENU_YUP)
    q = rotations.multiply(rotations.multiply(back, quaternion), _Q_ENU_YUP)
    return rotations.to_matrix(back) @ position, q
