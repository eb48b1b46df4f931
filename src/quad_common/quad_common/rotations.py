"""Rotations in one place. Quaternions are ROS order (x, y, z, w), Hamilton, active:
q maps body (FLU) vectors into the world (ENU) frame, v_world = R(q) v_body.

Every function accepts a single quaternion of shape (4,) or a stack (..., 4).
"""

import math

import numpy as np


def normalize(q):
    """q / |q|; raises on a zero or non-finite quaternion."""
    q = np.asarray(q, dtype=float)
    if q.shape == (4,):  # one quaternion (every message): math.hypot, ~10x cheaper than np.linalg.norm here
        n = math.hypot(*q.tolist())  # inf if any component is inf, nan if one is nan (and none inf)
        if not (math.isfinite(n) and n >= 1e-12):
            raise ValueError(f'quaternion must be finite and non-zero, got {q.tolist()}')
        return q / n
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if not np.all(np.isfinite(q)) or np.any(n < 1e-12):
        raise ValueError(f'quaternion must be finite and non-zero, got {q.tolist()}')
    return q / n


def multiply(q1, q2):
    """Hamilton product q1 * q2 (apply q2 first, then q1)."""
    q1, q2 = np.asarray(q1, dtype=float), np.asarray(q2, dtype=float)
    if q1.shape == q2.shape == (4,):  # one pair (every control tick): the same arithmetic on Python floats
        x1, y1, z1, w1 = q1.tolist()
        x2, y2, z2, w2 = q2.tolist()
        return np.array([w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2, w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                         w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2, w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2])
    x1, y1, z1, w1 = np.moveaxis(q1, -1, 0)
    x2, y2, z2, w2 = np.moveaxis(q2, -1, 0)
    return np.stack([
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
    ], axis=-1)


def conjugate(q):
    q = np.asarray(q, dtype=float)
    return q * np.array([-1.0, -1.0, -1.0, 1.0])


def to_matrix(q):
    """Rotation matrix R(q) (body -> world) of a unit quaternion."""
    q = np.asarray(q, dtype=float)
    if q.shape == (4,):  # one quaternion (every odometry message): the same arithmetic on Python floats
        x, y, z, w = q.tolist()
        return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                         [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                         [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    x, y, z, w = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], axis=-1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], axis=-1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=-1),
    ], axis=-2)


def rotate(q, v) -> tuple:
    """R(q) v for one quaternion and one vector, on Python floats (to_matrix's entries): ~1 us against ~5 us for
    to_matrix(q) @ v, every odometry message; the sums in index order (numpy's matmul may round the last bit
    differently)."""
    x, y, z, w = q
    vx, vy, vz = v
    return ((1 - 2 * (y * y + z * z)) * vx + 2 * (x * y - z * w) * vy + 2 * (x * z + y * w) * vz,
            2 * (x * y + z * w) * vx + (1 - 2 * (x * x + z * z)) * vy + 2 * (y * z - x * w) * vz,
            2 * (x * z - y * w) * vx + 2 * (y * z + x * w) * vy + (1 - 2 * (x * x + y * y)) * vz)


def rotate_back(q, v) -> tuple:
    """R(q)^T v = R(q*) v on Python floats, as rotate (the conjugate's entries are R(q)'s transposed, bit for bit:
    negating x, y and z is exact)."""
    x, y, z, w = q
    return rotate((-x, -y, -z, w), v)


def from_matrix(R):
    """Unit quaternion (w >= 0) of a rotation matrix (Shepperd's method, robust near 180 deg)."""
    R = np.asarray(R, dtype=float)
    if R.ndim > 2:
        return np.stack([from_matrix(r) for r in R.reshape(-1, 3, 3)]).reshape(R.shape[:-2] + (4,))
    tr = np.trace(R)
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = [(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = [0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s, (R[2, 1] - R[1, 2]) / s]
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = [(R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s, (R[0, 2] - R[2, 0]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = [(R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s, (R[1, 0] - R[0, 1]) / s]
    q = np.array(q)
    return q if q[3] >= 0 else -q


_SCALARS = (float, int, np.floating)


def from_euler(roll, pitch, yaw):
    """Quaternion of intrinsic Z-Y-X (yaw, then pitch, then roll) Euler angles, radians."""
    if isinstance(roll, _SCALARS) and isinstance(pitch, _SCALARS) and isinstance(yaw, _SCALARS):   # one: math
        cr, sr = math.cos(roll / 2), math.sin(roll / 2)
        cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
        cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
        return np.array([sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy,
                         cr * cp * cy + sr * sp * sy])
    cr, sr = np.cos(np.asarray(roll) / 2), np.sin(np.asarray(roll) / 2)
    cp, sp = np.cos(np.asarray(pitch) / 2), np.sin(np.asarray(pitch) / 2)
    cy, sy = np.cos(np.asarray(yaw) / 2), np.sin(np.asarray(yaw) / 2)
    return np.stack([
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    ], axis=-1)


def to_euler(q):
    """(roll, pitch, yaw) in radians, Z-Y-X convention; pitch clipped to [-pi/2, pi/2]."""
    x, y, z, w = np.moveaxis(np.asarray(q, dtype=float), -1, 0)
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.stack([roll, pitch, yaw], axis=-1)


def from_yaw(yaw):
    """Quaternion of a pure rotation by yaw (radians) about world z."""
    yaw = np.asarray(yaw, dtype=float)
    zero = np.zeros_like(yaw)
    return np.stack([zero, zero, np.sin(yaw / 2), np.cos(yaw / 2)], axis=-1)


def hat(v):
    """Skew matrix: hat(a) @ b = a x b."""
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def vee(S):
    """Inverse of hat for a skew(-ish) matrix: the vector of its antisymmetric part."""
    return np.array([S[2, 1] - S[1, 2], S[0, 2] - S[2, 0], S[1, 0] - S[0, 1]]) / 2.0


def wrap_angle(a):
    """Angle(s) wrapped to [-pi, pi)."""
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def from_body_z_and_yaw(b3, yaw):
    """The attitude whose body z axis is the unit vector b3 and whose heading is yaw (rad): b2 = b3 x (cos yaw,
    sin yaw, 0) normalised, b1 = b2 x b3 (b3 must not be horizontal along the heading)."""
    b3 = np.asarray(b3, dtype=float)
    b2 = np.cross(b3, [np.cos(yaw), np.sin(yaw), 0.0])
    b2 /= np.linalg.norm(b2)
    return from_matrix(np.column_stack([np.cross(b2, b3), b2, b3]))
