"""Control allocation: (collective thrust, body moments) -> rotor speeds, with deliberate saturation.

Per rotor i at body position (x_i, y_i) with spin direction d_i (+1 CCW), rotor thrust f_i = k_eta w_i^2:

    [T, Mx, My, Mz]^T = A f,   A rows: 1,  y_i,  -x_i,  -d_i k_m / k_eta

so f = A^-1 u. When f leaves [f_min, f_max] the command is reduced in priority order:
roll/pitch is kept first (scaled down only if its differential alone exceeds the rotor range),
then the collective thrust is shifted to fit, and yaw gets whatever headroom is left.
Each reduction is reported in the returned flags. Scalar Python: this runs every physics step.
"""

import math

import numpy as np

from quad_common.vehicle import Vehicle

ROLL_PITCH, THRUST, YAW = 'roll_pitch', 'thrust', 'yaw'


def allocation_matrix(vehicle: Vehicle) -> np.ndarray:
    """A with [T, Mx, My, Mz] = A @ rotor_thrusts_n."""
    positions, directions = vehicle.rotor_geometry()
    return np.array([np.ones(4), positions[:, 1], -positions[:, 0], -directions * vehicle.k_m / vehicle.k_eta])


class Mixer:
    def __init__(self, vehicle: Vehicle):
        self.k_eta = vehicle.k_eta
        self.allocation = allocation_matrix(vehicle)
        inverse = np.linalg.inv(self.allocation)
        self._b_thrust = tuple(map(float, inverse[:, 0]))
        self._b_mx = tuple(map(float, inverse[:, 1]))
        self._b_my = tuple(map(float, inverse[:, 2]))
        self._b_mz = tuple(map(float, inverse[:, 3]))
        self.speed_min_radps = vehicle.rotor_speed_min_radps
        self.speed_max_radps = vehicle.rotor_speed_max_radps
        self.f_min_n = self.k_eta * self.speed_min_radps ** 2
        self.f_max_n = self.k_eta * self.speed_max_radps ** 2

    def rotor_thrusts(self, thrust_n, moments_nm):
        """(rotor thrusts (4 floats, N), reduced axes (tuple of ROLL_PITCH/THRUST/YAW))."""
        mx, my, mz = float(moments_nm[0]), float(moments_nm[1]), float(moments_nm[2])
        lo, hi = self.f_min_n, self.f_max_n
        flags = ()
        rp = [bx * mx + by * my for bx, by in zip(self._b_mx, self._b_my)]
        span = max(rp) - min(rp)
        if span > hi - lo:
            scale = (hi - lo) / span
            rp = [v * scale for v in rp]
            flags += (ROLL_PITCH,)
        base = [bt * thrust_n + v for bt, v in zip(self._b_thrust, rp)]
        top, bottom = max(base), min(base)
        if top > hi:
            base = [v - (top - hi) for v in base]
            flags += (THRUST,)
        elif bottom < lo:
            base = [v + (lo - bottom) for v in base]
            flags += (THRUST,)
        yaw = [bz * mz for bz in self._b_mz]
        s = 1.0
        for b, y in zip(base, yaw):
            if y > 0.0 and b + y > hi:
                s = min(s, (hi - b) / y)
            elif y < 0.0 and b + y < lo:
                s = min(s, (lo - b) / y)
        if s < 1.0:
            flags += (YAW,)
            s = max(s, 0.0)
        return [min(max(b + s * y, lo), hi) for b, y in zip(base, yaw)], flags

    def rotor_speeds(self, thrust_n, moments_nm):
        """(rotor speed commands (4 floats, rad/s), reduced axes)."""
        thrusts, flags = self.rotor_thrusts(thrust_n, moments_nm)
        k = self.k_eta
        return [math.sqrt(f / k) for f in thrusts], flags

    def wrench(self, rotor_speeds_radps) -> np.ndarray:
        """[T, Mx, My, Mz] produced by the given rotor speeds (the inverse of rotor_speeds)."""
        w = np.asarray(rotor_speeds_radps, dtype=float)
        return self.allocation @ (self.k_eta * w * np.abs(w))
