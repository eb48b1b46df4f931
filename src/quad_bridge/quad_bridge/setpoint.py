"""Setpoint checks before anything is sent to a vehicle: finite values, tilt within max_tilt."""

import math
import struct

import numpy as np

from quad_common import rotations
from quad_common.conversions import UNSET_COVARIANCE
from quad_common.ros import cdr
from quad_common.types import AttitudeSetpoint

# sensor_msgs/Imu in little-endian plain CDR after the header's frame_id (8-aligned): orientation, its covariance[0],
# angular_velocity, its covariance[0], linear_acceleration.z and its covariance[0] (the fields a setpoint uses)
_IMU = struct.Struct('<4dd64x3dd64x2ddd')


def tilt_rad(quaternion) -> float:
    """Angle between body z and world z."""
    return math.acos(float(np.clip(rotations.to_matrix(quaternion)[2, 2], -1.0, 1.0)))


def _axis_angle(axis, angle) -> np.ndarray:
    return np.append(np.asarray(axis) * math.sin(angle / 2), math.cos(angle / 2))


def clamp_tilt(quaternion, max_tilt_rad: float) -> tuple[np.ndarray, bool]:
    """(q, clamped): q = q_tilt q_yaw with q_yaw a rotation about world z and q_tilt about a horizontal
    axis; an over-tilted attitude keeps its yaw part and tilt axis and gets the tilt angle max_tilt_rad."""
    q = rotations.normalize(quaternion)
    tilt = tilt_rad(q)
    if tilt <= max_tilt_rad:
        return q, False
    z_body = rotations.to_matrix(q)[:, 2]
    axis = np.cross([0.0, 0.0, 1.0], z_body)
    n = np.linalg.norm(axis)
    axis = axis / n if n > 1e-9 else np.array([1.0, 0.0, 0.0])  # upside down: any horizontal axis
    q_yaw = rotations.multiply(rotations.conjugate(_axis_angle(axis, tilt)), q)
    return rotations.normalize(rotations.multiply(_axis_angle(axis, max_tilt_rad), q_yaw)), True


def _within_tilt(sp: AttitudeSetpoint, max_tilt_rad: float) -> AttitudeSetpoint | None:
    """check_setpoint of a valid setpoint within max_tilt on Python floats (the same arithmetic as normalize,
    to_matrix and tilt_rad), else None: every setpoint goes
    through here, and the numpy path's per-call overhead would be most of its cost."""
    q, f, rates = sp.quaternion, sp.specific_force_mps2, sp.body_rates
    if not (isinstance(q, np.ndarray) and q.shape == (4,) and math.isfinite(f) and f >= 0.0):
        return None
    if rates is not None and not (np.shape(rates) == (3,) and all(map(math.isfinite, rates))):
        return None
    n = math.hypot(*q.tolist())
    if not (math.isfinite(n) and n >= 1e-12):
        return None
    q = np.asarray(q, dtype=float) / n
    x, y, _, _ = q.tolist()
    if math.acos(min(max(1 - 2 * (x * x + y * y), -1.0), 1.0)) > max_tilt_rad:
        return None
    return AttitudeSetpoint(quaternion=q, specific_force_mps2=float(f),
                            body_rates=None if rates is None else np.asarray(rates, float))


def check_setpoint(sp: AttitudeSetpoint, max_tilt_rad: float,
                   max_specific_force_mps2: float = math.inf) -> tuple[AttitudeSetpoint, bool, bool]:
    """(safe setpoint, tilt was clamped, vertical acceleration kept). Raises ValueError naming the field on
    NaN/inf or a zero quaternion, or a negative thrust.

    A clamped setpoint keeps its vertical acceleration: it asked for the vertical specific force f cos(tilt);
    at the clamped tilt t_c that needs f' = f cos(tilt) / cos(t_c) (the 1/cos relation), limited to
    max_specific_force_mps2 (the thrust the vehicle can make); `kept` is False when that limit cut it."""
    fast = _within_tilt(sp, max_tilt_rad)
    if fast is not None:
        return fast, False, True
    if not np.all(np.isfinite(sp.quaternion)):
        raise ValueError(f'setpoint quaternion must be finite, got {np.asarray(sp.quaternion).tolist()}')
    if not math.isfinite(sp.specific_force_mps2) or sp.specific_force_mps2 < 0.0:
        raise ValueError(f'setpoint specific_force_mps2 must be finite and >= 0, got {sp.specific_force_mps2}')
    if sp.body_rates is not None and not np.all(np.isfinite(sp.body_rates)):
        raise ValueError(f'setpoint body_rates must be finite, got {np.asarray(sp.body_rates).tolist()}')
    q, clamped = clamp_tilt(sp.quaternion, max_tilt_rad)
    f, kept = float(sp.specific_force_mps2), True
    if clamped:
        f_vertical = f * float(rotations.to_matrix(rotations.normalize(sp.quaternion))[2, 2])
        needed = max(f_vertical, 0.0) / math.cos(max_tilt_rad)
        f, kept = min(needed, max_specific_force_mps2), needed <= max_specific_force_mps2 * (1 + 1e-9)
    rates = None if sp.body_rates is None else np.asarray(sp.body_rates, float)
    return AttitudeSetpoint(quaternion=q, specific_force_mps2=f, body_rates=rates), clamped, kept


def setpoint_from_cdr(raw: bytes, max_tilt_rad: float, max_specific_force_mps2: float = math.inf):
    """check_setpoint(cdr.imu_to_setpoint(raw), ...) of a serialized cmd/attitude_thrust: for a valid setpoint
    within max_tilt read and checked on Python floats with the same arithmetic (the quaternion normalised by
    imu_to_setpoint and again by the check, as there), anything else (another encoding, unset fields, NaN, a
    negative thrust, a tilt to clamp) the ordinary way, with its errors. Every setpoint comes through here; arrays
    between would be much of the setpoint path's Python."""
    fast = _fast_setpoint(raw, max_tilt_rad)
    if fast is not None:
        return fast, False, True
    return check_setpoint(cdr.imu_to_setpoint(raw), max_tilt_rad, max_specific_force_mps2)


def _fast_setpoint(raw, max_tilt_rad):
    if raw[:4] != cdr.CDR_LE or len(raw) < 16:
        return None
    offset = 8 + 4 + int.from_bytes(raw[12:16], 'little')   # body offset after the stamp and the frame_id string
    offset += -offset % 8
    if 4 + offset + _IMU.size > len(raw):
        return None
    qx, qy, qz, qw, q_cov0, rx, ry, rz, rates_cov0, _, _, f, f_cov0 = _IMU.unpack_from(raw, 4 + offset)
    if q_cov0 == UNSET_COVARIANCE or f_cov0 == UNSET_COVARIANCE or not (math.isfinite(f) and f >= 0.0):
        return None
    q = (qx, qy, qz, qw)
    for _ in range(2):   # rotations.normalize in imu_to_setpoint, then again in the check (_within_tilt)
        n = math.hypot(*q)
        if not (math.isfinite(n) and n >= 1e-12):
            return None
        q = tuple(c / n for c in q)
    x, y = q[0], q[1]
    if math.acos(min(max(1 - 2 * (x * x + y * y), -1.0), 1.0)) > max_tilt_rad:
        return None
    rates = None
    if rates_cov0 != UNSET_COVARIANCE:
        if not (math.isfinite(rx) and math.isfinite(ry) and math.isfinite(rz)):
            return None
        rates = np.array((rx, ry, rz))
    return AttitudeSetpoint(quaternion=np.array(q), specific_force_mps2=float(f), body_rates=rates)
