"""The seed's equation 6: the attitude PD that the vehicle's onboard autopilot runs.

    u2 = I [ kp_phi (phi_des - phi)       + kd_phi (p_des - p)
             kp_theta (theta_des - theta) + kd_theta (q_des - q)
             kp_psi (psi_des - psi)       + kd_psi (r_des - r) ]

with the seed's p_des = q_des = 0 and r_des = the yaw-rate feed-forward, or, with
use_feedforward_rates, all three feed-forward body rates of the setpoint. quad_sim calls this
at its physics rate; it is written only here.
"""

import numpy as np

from quad_common import rotations
from quad_common.types import AttitudeSetpoint
from quad_common.vehicle import AttitudeGains


def attitude_moments(quaternion, body_rates, setpoint: AttitudeSetpoint, gains: AttitudeGains,
                     inertia_kgm2, use_feedforward_rates: bool = False) -> np.ndarray:
    """Body moments u2 (N m, FLU) from the current attitude/rates and the setpoint."""
    angles = rotations.to_euler(quaternion)
    angles_des = rotations.to_euler(setpoint.quaternion)
    angle_error = rotations.wrap_angle(angles_des - angles)
    rates_des = np.zeros(3)
    if setpoint.body_rates is not None:
        rates_des = setpoint.body_rates.copy() if use_feedforward_rates else np.array([0, 0, setpoint.body_rates[2]])
    inertia = np.asarray(inertia_kgm2, dtype=float)
    inertia = np.diag(inertia) if inertia.ndim == 1 else inertia
    return inertia @ (gains.kp * angle_error + gains.kd * (rates_des - np.asarray(body_rates, dtype=float)))
