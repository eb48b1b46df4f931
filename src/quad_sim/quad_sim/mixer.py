"""Control allocation: (collective thrust, body moments) -> rotor speeds, with deliberate saturation.

Per rotor i at body position (x_i, y_i) with spin direction d_i (+1 CCW), rotor thrust f_i = k_eta w_i^2:

    [T, Mx, My, Mz]^T = A f,   A rows: 1,  y_i,  -x_i,  -d_i k_m / k_eta

so f = A^-1 u. When f leaves [f_min, f_max] the command is reduced in priority order:
roll/pitch is kept first (scaled down only if its differential alone exceeds the rotor range),
then the collective thrust is shifted to fit, and yaw gets whatever headroom is left.
Each reduction is reported in the returned flags. `rotor_commands` is the compiled kernel that runs
every physics step (quad_common.compiled); the Mixer methods wrap it.
"""

import math

import numpy as np

from quad_common.compiled import njit
from quad_common.vehicle import Vehicle

ROLL_PITCH, THRUST, YAW = 'roll_pitch', 'thrust', 'yaw'
FLAG_BITS = ((1, ROLL_PITCH), (2, THRUST), (4, YAW))
# parameter vector: columns of A^-1 for T, Mx, My, Mz (4 each), f_min, f_max, k_eta
B_THRUST, B_MX, B_MY, B_MZ, F_MIN, F_MAX, K_ETA = 0, 4, 8, 12, 16, 17, 18


def allocation_matrix(vehicle: Vehicle) -> np.ndarray:
    """A with [T, Mx, My, Mz] = A @ rotor_thrusts_n."""
    positions, directions = vehicle.rotor_geometry()
    return np.array([np.ones(4), positions[:, 1], -positions[:, 0], -directions * vehicle.k_m / vehicle.k_eta])


def flag_names(bits: int) -> tuple:
    """The reduced axes (ROLL_PITCH, THRUST, YAW) of a kernel's flag bits."""
    return tuple(name for bit, name in FLAG_BITS if bits & bit)


@njit
def rotor_commands(thrust_n, mx, my, mz, p, thrusts_out, speeds_out):
    """Rotor thrusts (N) and speed commands (rad/s) into the 4-arrays; returns the reduced axes as bits."""
    lo, hi = p[F_MIN], p[F_MAX]
    flags = 0
    rp = np.empty(4)
    for i in range(4):
        rp[i] = p[B_MX + i] * mx + p[B_MY + i] * my
    span = rp.max() - rp.min()
    if span > hi - lo:
        scale = (hi - lo) / span
        for i in range(4):
            rp[i] = rp[i] * scale
        flags |= 1
    base = np.empty(4)
    for i in range(4):
        base[i] = p[B_THRUST + i] * thrust_n + rp[i]
    top, bottom = base.max(), base.min()
    if top > hi:
        for i in range(4):
            base[i] = base[i] - (top - hi)
        flags |= 2
    elif bottom < lo:
        for i in range(4):
            base[i] = base[i] + (lo - bottom)
        flags |= 2
    s = 1.0
    for i in range(4):
        y = p[B_MZ + i] * mz
        if y > 0.0 and base[i] + y > hi:
            s = min(s, (hi - base[i]) / y)
        elif y < 0.0 and base[i] + y < lo:
            s = min(s, (lo - base[i]) / y)
    if s < 1.0:
        flags |= 4
        s = max(s, 0.0)
    for i in range(4):
        f = min(max(base[i] + s * (p[B_MZ + i] * mz), lo), hi)
        thrusts_out[i] = f
        speeds_out[i] = math.sqrt(f / p[K_ETA])
    return flags


class Mixer:
    def __init__(self, vehicle: Vehicle):
        self.k_eta = vehicle.k_eta
        self.allocation = allocation_matrix(vehicle)
        inverse = np.linalg.inv(self.allocation)
        self.speed_min_radps = vehicle.rotor_speed_min_radps
        self.speed_max_radps = vehicle.rotor_speed_max_radps
        self.f_min_n = self.k_eta * self.speed_min_radps ** 2
        self.f_max_n = self.k_eta * self.speed_max_radps ** 2
        self.params = np.concatenate([inverse[:, 0], inverse[:, 1], inverse[:, 2], inverse[:, 3],
                                      [self.f_min_n, self.f_max_n, self.k_eta]]).astype(np.float64)

    def _run(self, thrust_n, moments_nm):
        thrusts, speeds = np.empty(4), np.empty(4)
        bits = rotor_commands(float(thrust_n), float(moments_nm[0]), float(moments_nm[1]), float(moments_nm[2]),
                              self.params, thrusts, speeds)
        return thrusts.tolist(), speeds.tolist(), flag_names(bits)

    def rotor_thrusts(self, thrust_n, moments_nm):
        """(rotor thrusts (4 floats, N), reduced axes (tuple of ROLL_PITCH/THRUST/YAW))."""
        thrusts, _, flags = self._run(thrust_n, moments_nm)
        return thrusts, flags

    def rotor_speeds(self, thrust_n, moments_nm):
        """(rotor speed commands (4 floats, rad/s), reduced axes)."""
        _, speeds, flags = self._run(thrust_n, moments_nm)
        return speeds, flags

    def wrench(self, rotor_speeds_radps) -> np.ndarray:
        """[T, Mx, My, Mz] produced by the given rotor speeds (the inverse of rotor_speeds)."""
        w = np.asarray(rotor_speeds_radps, dtype=float)
        return self.allocation @ (self.k_eta * w * np.abs(w))
