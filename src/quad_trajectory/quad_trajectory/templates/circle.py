"""A trajectory class in rotorpy's interface (`update(t) -> flat_output`), flown as a mission's generator:

    trajectory:
      generator: quad_trajectory.templates.circle:Circle
      generator_args: {radius_m: 1.0, laps: 1.0, period_s: 8.0}

Built Circle(waypoints, **generator_args): waypoints is the mission's (N, 3) array (metres, world ENU, z up); this
one starts at the first and flies `laps` circles of radius_m around a centre radius_m behind it (-x), at its height,
starting and ending at rest (a quintic time scaling). flat_output: x, x_dot, x_ddot, x_dddot, x_ddddot (3 each),
yaw, yaw_dot, yaw_ddot; quadflight samples x .. x_ddot and yaw, yaw_dot, yaw_ddot over [0, duration_s].
"""

import numpy as np


class Circle:
    def __init__(self, waypoints, radius_m=1.0, laps=1.0, period_s=8.0):
        self.start = np.asarray(waypoints, dtype=float)[0]
        self.radius_m, self.angle_rad = float(radius_m), 2 * np.pi * float(laps)
        self.duration_s = float(period_s) * float(laps)   # quadflight samples it this long

    def update(self, t):
        tau = min(max(t / self.duration_s, 0.0), 1.0)
        s = tau ** 3 * (10 - 15 * tau + 6 * tau ** 2)                    # 0 -> 1, at rest at both ends
        ds = 30 * tau ** 2 * (1 - tau) ** 2 / self.duration_s
        dds = 60 * tau * (1 - tau) * (1 - 2 * tau) / self.duration_s ** 2
        theta, w, dw = self.angle_rad * s, self.angle_rad * ds, self.angle_rad * dds
        radial, tangent = np.array([np.cos(theta), np.sin(theta), 0.0]), np.array([-np.sin(theta), np.cos(theta), 0.0])
        centre = self.start - np.array([self.radius_m, 0.0, 0.0])
        zero = np.zeros(3)
        return {'x': centre + self.radius_m * radial, 'x_dot': self.radius_m * w * tangent,
                'x_ddot': self.radius_m * (dw * tangent - w * w * radial), 'x_dddot': zero, 'x_ddddot': zero,
                'yaw': 0.0, 'yaw_dot': 0.0, 'yaw_ddot': 0.0}
