"""A controller in quadflight's own types (quad_control.plugins.ControllerPlugin): copy this file, change update().

Fly it:  ./quadflight fly config/missions/maze.yaml --controller quad_control.templates.my_controller:MyController
(your copy: `--controller my_package.my_controller:MyController`, with my_package importable: docs/plugins.md).

Frames: world ENU (z up), body FLU; quaternions (x, y, z, w) rotating body into world; SI units.
state:     position, velocity (world, m, m/s), quaternion, body_rates (rad/s)
reference: position, velocity, acceleration, jerk (world), yaw, yaw_rate
return:    AttitudeSetpoint(quaternion, specific_force_mps2 = thrust / mass along body z, body_rates feed-forward or
           None); the vehicle's own attitude loop (the simulator's, the autopilot's) flies it.
"""

import numpy as np

from quad_common import rotations
from quad_common.types import GRAVITY_MPS2, AttitudeSetpoint
from quad_control.plugins import ControllerPlugin


class MyController(ControllerPlugin):
    """PD on position, then the attitude whose thrust axis points along the desired force (with the plan's yaw).
    Its gains are position_controller's kp_x.. kd_z (self.gains: a control profile's, a sweep's, tune's search)."""

    def __init__(self, vehicle, params):
        super().__init__(vehicle, params)
        self.mass_kg = params['mass']          # also vehicle.mass_kg

    def reset(self):
        """A plan starts (or a hand-over engages): clear integrators and filters here."""

    def update(self, state, reference, dt_s):
        kp, kd = self.gains.kp, self.gains.kd   # 1/s^2, 1/s per axis
        acc = kp * (reference.position - state.position) + kd * (reference.velocity - state.velocity) \
            + reference.acceleration
        force = self.mass_kg * (acc + np.array([0.0, 0.0, GRAVITY_MPS2]))
        b3 = force / np.linalg.norm(force)
        heading = np.array([np.cos(reference.yaw), np.sin(reference.yaw), 0.0])
        b2 = np.cross(b3, heading)
        b2 /= np.linalg.norm(b2)
        attitude = np.column_stack([np.cross(b2, b3), b2, b3])
        body_z = rotations.to_matrix(state.quaternion)[:, 2]
        thrust_n = float(force @ body_z)
        return AttitudeSetpoint(quaternion=rotations.from_matrix(attitude), specific_force_mps2=thrust_n / self.mass_kg,
                                body_rates=np.array([0.0, 0.0, reference.yaw_rate]))
