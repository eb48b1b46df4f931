"""A controller in the flightsim / rotorpy interface, flown unchanged through quad_control.plugins' adapter.

Fly it:  ./quadflight fly config/missions/maze.yaml --controller quad_control.templates.flightsim_controller:SE3Control

Built with the vehicle's parameters as rotorpy names them (quad_control.plugins.vehicle_params: mass, Ixx, Iyy, Izz,
arm_length, k_eta / k_thrust, k_m / k_drag, rotor_speed_min, rotor_speed_max, ...). update(t, state, flat_output):
state x, v (m, m/s, world z up), q (x, y, z, w body -> world), w (body rates, rad/s); flat_output x, x_dot, x_ddot,
x_dddot, x_ddddot, yaw, yaw_dot, yaw_ddot. quadflight flies cmd_thrust (N) and cmd_q (the attitude / thrust setpoint
"for the laboratory"); cmd_motor_speeds and cmd_moment are ignored (the vehicle's attitude loop makes them).
"""

import numpy as np
from scipy.spatial.transform import Rotation


class SE3Control:
    def __init__(self, quad_params):
        self.mass = quad_params['mass']
        self.g = 9.81
        self.kp_pos = np.array([6.5, 6.5, 15.0])
        self.kd_pos = np.array([4.0, 4.0, 9.0])

    def update(self, t, state, flat_output):
        pos_err = state['x'] - flat_output['x']
        vel_err = state['v'] - flat_output['x_dot']
        F_des = self.mass * (-self.kp_pos * pos_err - self.kd_pos * vel_err + flat_output['x_ddot']
                             + np.array([0.0, 0.0, self.g]))
        R = Rotation.from_quat(state['q']).as_matrix()
        u1 = float(F_des @ R[:, 2])
        b3 = F_des / np.linalg.norm(F_des)
        c1 = np.array([np.cos(flat_output['yaw']), np.sin(flat_output['yaw']), 0.0])
        b2 = np.cross(b3, c1)
        b2 /= np.linalg.norm(b2)
        R_des = np.column_stack([np.cross(b2, b3), b2, b3])
        return {'cmd_motor_speeds': np.zeros(4), 'cmd_thrust': u1, 'cmd_moment': np.zeros(3),
                'cmd_q': Rotation.from_matrix(R_des).as_quat()}
