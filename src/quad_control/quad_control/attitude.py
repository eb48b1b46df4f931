"""The seed's equation 6: the attitude PD that the vehicle's onboard autopilot runs.

    u2 = I [ kp_phi (phi_des - phi)       + kd_phi (p_des - p)
             kp_theta (theta_des - theta) + kd_theta (q_des - q)
             kp_psi (psi_des - psi)       + kd_psi (r_des - r) ]

with the seed's p_des = q_des = 0 and r_des = the yaw-rate feed-forward, or, with
use_feedforward_rates, all three feed-forward body rates of the setpoint. quad_sim calls this
at its physics rate; it is written only here.

attitude_error='euler' (default) is the seed's per-axis Z-Y-X angle difference; 'so3' replaces it
by the geometric error -e_R, e_R = vee(R_des^T R - R^T R_des) / 2 (Lee et al. 2010), which agrees
with the Euler form near hover and stays meaningful at large tilt.
"""

import numpy as np

from quad_common import rotations
from quad_common.types import AttitudeSetpoint
from quad_common.vehicle import AttitudeGains


def attitude_moments(quaternion, body_rates, setpoint: AttitudeSetpoint, gains: AttitudeGains,
                     inertia_kgm2, use_feedforward_rates: bool = False, attitude_error: str = 'euler') -> np.ndarray:
    """Body moments u2 (N m, FLU) from the current attitude/rates and the setpoint."""
    if attitude_error == 'euler':
        angle_error = rotations.wrap_angle(rotations.to_euler(setpoint.quaternion) - rotations.to_euler(quaternion))
    elif attitude_error == 'so3':
        rot, rot_des = rotations.to_matrix(quaternion), rotations.to_matrix(setpoint.quaternion)
        angle_error = -0.5 * rotations.vee(rot_des.T @ rot - rot.T @ rot_des)
    else:
        raise ValueError(f"attitude_error = {attitude_error!r} must be 'euler' or 'so3'")
    rates_des = np.zeros(3)
    if setpoint.body_rates is not None:
        rates_des = setpoint.body_rates.copy() if use_feedforward_rates else np.array([0, 0, setpoint.body_rates[2]])
    inertia = np.asarray(inertia_kgm2, dtype=float)
    inertia = np.diag(inertia) if inertia.ndim == 1 else inertia
    return inertia @ (gains.kp * angle_error + gains.kd * (rates_des - np.asarray(body_rates, dtype=float)))
