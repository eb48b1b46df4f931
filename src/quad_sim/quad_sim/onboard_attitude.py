"""The seed's equation 6: the attitude PD that the vehicle's onboard autopilot runs.

    u2 = I [ kp_phi (phi_des - phi)       + kd_phi (p_des - p)
             kp_theta (theta_des - theta) + kd_theta (q_des - q)
             kp_psi (psi_des - psi)       + kd_psi (r_des - r) ]

with the seed's p_des = q_des = 0 and r_des = the yaw-rate feed-forward, or, with
use_feedforward_rates, all three feed-forward body rates of the setpoint. quad_sim calls the kernel
`moments` at its physics rate from its own compiled step; it is written only here.

attitude_error='euler' (default) is the seed's per-axis Z-Y-X angle difference; 'so3' replaces it
by the geometric error -e_R, e_R = vee(R_des^T R - R^T R_des) / 2 (Lee et al. 2010), which agrees
with the Euler form near hover and stays meaningful at large tilt.
"""

import math

import numpy as np

from quad_common.compiled import float_array, njit
from quad_common.types import AttitudeSetpoint
from quad_common.vehicle import AttitudeGains

ATTITUDE_ERRORS = ('euler', 'so3')


@njit
def _euler(q):
    """(roll, pitch, yaw) Z-Y-X of q = (x, y, z, w), as quad_common.rotations.to_euler."""
    x, y, z, w = q[0], q[1], q[2], q[3]
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(min(max(2 * (w * y - z * x), -1.0), 1.0))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


@njit
def _wrap(a):
    return (a + math.pi) % (2 * math.pi) - math.pi


@njit
def _rotation(q):
    x, y, z, w = q[0], q[1], q[2], q[3]
    r = np.empty((3, 3))
    r[0, 0], r[0, 1], r[0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)
    r[1, 0], r[1, 1], r[1, 2] = 2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)
    r[2, 0], r[2, 1], r[2, 2] = 2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)
    return r


@njit
def moments(quaternion, body_rates, quaternion_des, rates_des, kp, kd, inertia, so3):
    """Equation 6 on float64 arrays (quaternions (4,), rates/gains (3,), inertia (3, 3)); (Mx, My, Mz) in N m."""
    e = np.empty(3)
    if so3:
        r, rd = _rotation(quaternion), _rotation(quaternion_des)
        m = np.empty((3, 3))  # R_des^T R - R^T R_des
        for i in range(3):
            for j in range(3):
                m[i, j] = (rd[0, i] * r[0, j] + rd[1, i] * r[1, j] + rd[2, i] * r[2, j]
                           - r[0, i] * rd[0, j] - r[1, i] * rd[1, j] - r[2, i] * rd[2, j])
        e[0], e[1], e[2] = -0.5 * m[2, 1], -0.5 * m[0, 2], -0.5 * m[1, 0]
    else:
        roll, pitch, yaw = _euler(quaternion)
        roll_des, pitch_des, yaw_des = _euler(quaternion_des)
        e[0], e[1], e[2] = _wrap(roll_des - roll), _wrap(pitch_des - pitch), _wrap(yaw_des - yaw)
    a = np.empty(3)
    for i in range(3):
        a[i] = kp[i] * e[i] + kd[i] * (rates_des[i] - body_rates[i])
    return (inertia[0, 0] * a[0] + inertia[0, 1] * a[1] + inertia[0, 2] * a[2],
            inertia[1, 0] * a[0] + inertia[1, 1] * a[1] + inertia[1, 2] * a[2],
            inertia[2, 0] * a[0] + inertia[2, 1] * a[1] + inertia[2, 2] * a[2])


def desired_rates(setpoint: AttitudeSetpoint, use_feedforward_rates: bool = False) -> np.ndarray:
    """(p_des, q_des, r_des): the seed's (0, 0, yaw-rate feed-forward), or all three with use_feedforward_rates."""
    rates = np.zeros(3)
    if setpoint.body_rates is not None:
        if use_feedforward_rates:
            rates[:] = setpoint.body_rates
        else:
            rates[2] = setpoint.body_rates[2]
    return rates


def inertia_matrix(inertia_kgm2) -> np.ndarray:
    inertia = float_array(inertia_kgm2)
    return np.diag(inertia) if inertia.ndim == 1 else inertia


def attitude_moments(quaternion, body_rates, setpoint: AttitudeSetpoint, gains: AttitudeGains,
                     inertia_kgm2, use_feedforward_rates: bool = False, attitude_error: str = 'euler') -> np.ndarray:
    """Body moments u2 (N m, FLU) from the current attitude/rates and the setpoint."""
    if attitude_error not in ATTITUDE_ERRORS:
        raise ValueError(f"attitude_error = {attitude_error!r} must be 'euler' or 'so3'")
    return np.array(moments(float_array(quaternion), float_array(body_rates), float_array(setpoint.quaternion),
                            desired_rates(setpoint, use_feedforward_rates), float_array(gains.kp),
                            float_array(gains.kd), inertia_matrix(inertia_kgm2), attitude_error == 'so3'))
