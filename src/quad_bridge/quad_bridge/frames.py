"""ROS (world ENU, body FLU) <-> MAVLink (world NED, body FRD): the only place this conversion is written.

World: (x, y, z)_ENU -> (y, x, -z)_NED, a 180 deg rotation about (1, 1, 0)/sqrt(2); it is its own inverse.
Body:  (x, y, z)_FLU -> (x, -y, -z)_FRD, a 180 deg rotation about body x; also its own inverse.
Attitude: R_NED_FRD = R_NED_ENU R_ENU_FLU R_FLU_FRD, so yaw_NED = 90 deg - yaw_ENU.
ROS quaternions are (x, y, z, w); MAVLink quaternions are (w, x, y, z).
"""

import numpy as np

from quad_common.types import State

_S = np.sqrt(0.5)
S = float(_S)   # the same number as a Python float
Q_NED_ENU = np.array([_S, _S, 0.0, 0.0])     # ENU vectors -> NED vectors
Q_FLU_FRD = np.array([1.0, 0.0, 0.0, 0.0])   # FRD vectors -> FLU vectors


def world_enu_ned(v):
    """(x, y, z) -> (y, x, -z): ENU -> NED and, being an involution, NED -> ENU."""
    v = np.asarray(v, dtype=float)
    if v.ndim == 1:   # one vector (every telemetry message): np.stack costs 5x
        return np.array([v[1], v[0], -v[2]])
    return np.stack([v[..., 1], v[..., 0], -v[..., 2]], axis=-1)


def body_flu_frd(v):
    """(x, y, z) -> (x, -y, -z): FLU -> FRD and FRD -> FLU (body rates, body velocities, forces)."""
    v = np.asarray(v, dtype=float)
    if v.ndim == 1:
        return np.array([v[0], -v[1], -v[2]])
    return np.stack([v[..., 0], -v[..., 1], -v[..., 2]], axis=-1)


def quaternion_enu_to_ned(q_enu_flu):
    """Attitude body FLU -> world ENU, (x,y,z,w), to attitude body FRD -> world NED, (x,y,z,w), w >= 0:
    q_NED_ENU * q * q_FLU_FRD, which multiplied out is s (-x - y, y - x, z - w, -w - z), s = sqrt(1/2).
    Both fixed rotations are 180 degree turns, so the map is its own inverse (with w >= 0)."""
    q = np.asarray(q_enu_flu, dtype=float)
    if q.ndim == 1:
        x, y, z, w = q.tolist()
        sign = -_S if -w - z < 0 else _S
        return np.array([sign * (-x - y), sign * (y - x), sign * (z - w), sign * (-w - z)])
    x, y, z, w = np.moveaxis(q, -1, 0)
    out = _S * np.stack([-x - y, y - x, z - w, -w - z], axis=-1)
    return np.where(out[..., 3:4] < 0, -out, out)


def quaternion_ned_to_enu(q_ned_frd):
    """Inverse of quaternion_enu_to_ned: conj(q_NED_ENU) * q * conj(q_FLU_FRD) multiplies out to the same map."""
    return quaternion_enu_to_ned(q_ned_frd)


def state_to_ned(state: State) -> State:
    """A ROS state (ENU/FLU) expressed in MAVLink's frames (NED/FRD); body rates stay body rates."""
    return State(position=world_enu_ned(state.position), velocity=world_enu_ned(state.velocity),
                 quaternion=quaternion_enu_to_ned(state.quaternion), body_rates=body_flu_frd(state.body_rates))


def state_from_ned(state_ned: State) -> State:
    """Inverse of state_to_ned: a MAVLink state (NED/FRD) in ROS frames (ENU/FLU)."""
    return State(position=world_enu_ned(state_ned.position), velocity=world_enu_ned(state_ned.velocity),
                 quaternion=quaternion_ned_to_enu(state_ned.quaternion),
                 body_rates=body_flu_frd(state_ned.body_rates))


def enu_to_mavlink_quaternion(q_enu_flu) -> list:
    """to_mavlink_quaternion(quaternion_enu_to_ned(q)) of one quaternion on Python floats: the same arithmetic
    without the two numpy arrays between (every setpoint sent; ~4.6 us -> ~1 us)."""
    x, y, z, w = np.asarray(q_enu_flu, dtype=float).tolist()
    sign = -_S if -w - z < 0 else _S
    return [sign * (-w - z), sign * (-x - y), sign * (y - x), sign * (z - w)]


def to_mavlink_quaternion(q_xyzw):
    """(x, y, z, w) -> [w, x, y, z] as plain floats."""
    x, y, z, w = (float(c) for c in q_xyzw)
    return [w, x, y, z]


def from_mavlink_quaternion(q_wxyz):
    """[w, x, y, z] -> (x, y, z, w) array."""
    w, x, y, z = (float(c) for c in q_wxyz)
    return np.array([x, y, z, w])
