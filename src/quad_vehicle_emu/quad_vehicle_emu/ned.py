"""The simulator's frames (world ENU, body FLU) as the autopilots report them (world NED, body FRD).

Written here with rotation matrices on purpose, not taken from quad_bridge.frames: the two ends of the link
must not share a conversion, or a sign error would cancel out.
NED = P ENU with P = [[0,1,0],[1,0,0],[0,0,-1]]; FRD = B FLU with B = diag(1,-1,-1);
R_ned_frd = P R_enu_flu B (MAVLink quaternions are w, x, y, z).
"""

import numpy as np

from quad_common import rotations

P_NED_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
B_FLU_FRD = np.diag([1.0, -1.0, -1.0])


def enu_to_ned(v) -> np.ndarray:
    return P_NED_ENU @ np.asarray(v, dtype=float)


def flu_to_frd(v) -> np.ndarray:
    return B_FLU_FRD @ np.asarray(v, dtype=float)


frd_to_flu = flu_to_frd


def attitude_to_ned_wxyz(q_enu_flu_xyzw) -> list[float]:
    """MAVLink [w, x, y, z] of the body FRD -> world NED rotation."""
    R = P_NED_ENU @ rotations.to_matrix(q_enu_flu_xyzw) @ B_FLU_FRD
    x, y, z, w = rotations.from_matrix(R)
    return [float(w), float(x), float(y), float(z)]


def attitude_from_ned_wxyz(q_wxyz) -> np.ndarray:
    """ENU/FLU quaternion (x, y, z, w) of a MAVLink NED/FRD attitude [w, x, y, z] (normalised)."""
    w, x, y, z = (float(c) for c in q_wxyz)
    R_ned = rotations.to_matrix(rotations.normalize(np.array([x, y, z, w])))
    return rotations.from_matrix(P_NED_ENU @ R_ned @ B_FLU_FRD)

