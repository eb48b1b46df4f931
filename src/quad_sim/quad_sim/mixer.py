"""Control allocation: (collective thrust, body moments) -> rotor speeds, with deliberate saturation.

Per rotor i at body position (x_i, y_i) with spin direction d_i (+1 CCW), rotor thrust f_i = k_eta w_i^2:

    [T, Mx, My, Mz]^T = A f,   A rows: 1,  y_i,  -x_i,  -d_i k_m / k_eta

so f = A^-1 u. When f leaves [f_min, f_max] the command is reduced in this priority order (PX4's
sequential desaturation, ControlAllocationSequentialDesaturation: roll/pitch first, yaw last, with its
MINIMUM_YAW_MARGIN of 15 % of the range bought from the thrust):
1. the yaw demand is limited to YAW_DEMAND_SHARE of the rotor range per rotor (|Mz| <= yaw_limit_nm):
   more yaw moment than that only ever starves roll/pitch or thrust;
2. roll/pitch is kept (scaled down only if its differential alone exceeds the rotor range);
3. the collective thrust is shifted to fit roll/pitch (up or down);
4. yaw gets the headroom left, where the upper bound is raised by YAW_MARGIN of the range: the largest
   yaw scale s in [0, 1] for which, after lowering the thrust by at most that margin, every rotor is in
   range. Yaw never changes roll/pitch, and never raises the thrust.
Each reduction is reported in the returned flags (ROLL_PITCH, THRUST, YAW). `rotor_commands` is the
compiled kernel that runs every physics step (quad_common.compiled); the Mixer methods wrap it.
"""

import math

import numpy as np

from quad_common.compiled import njit
from quad_common.vehicle import Vehicle

ROLL_PITCH, THRUST, YAW = 'roll_pitch', 'thrust', 'yaw'
FLAG_BITS = ((1, ROLL_PITCH), (2, THRUST), (4, YAW))
# parameter vector: columns of A^-1 for T, Mx, My, Mz (4 each), f_min, f_max, k_eta, yaw moment limit
B_THRUST, B_MX, B_MY, B_MZ, F_MIN, F_MAX, K_ETA, YAW_LIMIT = 0, 4, 8, 12, 16, 17, 18, 19
YAW_DEMAND_SHARE = 0.25   # the largest yaw demand moves each rotor by this share of its thrust range
YAW_MARGIN = 0.15         # PX4's MINIMUM_YAW_MARGIN: yaw may lower the thrust by this share of the range


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
    limit = p[YAW_LIMIT]
    if mz > limit or mz < -limit:
        mz = limit if mz > 0.0 else -limit
        flags |= 4
    y = np.empty(4)
    for i in range(4):
        y[i] = p[B_MZ + i] * mz
    margin = YAW_MARGIN * (hi - lo)
    s = 1.0
    if not _yaw_fits(base, y, 1.0, lo, hi, margin):
        flags |= 4
        a, b = 0.0, 1.0
        for _ in range(40):  # feasible scales form an interval [0, s*]: bisect its end
            mid = 0.5 * (a + b)
            if _yaw_fits(base, y, mid, lo, hi, margin):
                a = mid
            else:
                b = mid
        s = a
    top = -1e300
    for i in range(4):
        top = max(top, base[i] + s * y[i])
    shift = top - hi if top > hi else 0.0
    if shift > 0.0:
        flags |= 2
    for i in range(4):
        f = min(max(base[i] + s * y[i] - shift, lo), hi)
        thrusts_out[i] = f
        speeds_out[i] = math.sqrt(f / p[K_ETA])
    return flags


@njit
def _yaw_fits(base, y, s, lo, hi, margin):
    """Whether yaw scale s fits: every rotor in [lo, hi] after lowering all by max(0, top - hi) <= margin."""
    top, bottom = -1e300, 1e300
    for i in range(4):
        f = base[i] + s * y[i]
        top, bottom = max(top, f), min(bottom, f)
    shift = top - hi if top > hi else 0.0
    return shift <= margin and bottom - shift >= lo - 1e-15


class Mixer:
    def __init__(self, vehicle: Vehicle):
        self.k_eta = vehicle.k_eta
        self.allocation = allocation_matrix(vehicle)
        inverse = np.linalg.inv(self.allocation)
        self.speed_min_radps = vehicle.rotor_speed_min_radps
        self.speed_max_radps = vehicle.rotor_speed_max_radps
        self.f_min_n = self.k_eta * self.speed_min_radps ** 2
        self.f_max_n = self.k_eta * self.speed_max_radps ** 2
        # |Mz| that moves each rotor by YAW_DEMAND_SHARE of its range (the A^-1 yaw column is +-k_eta / (4 k_m))
        self.yaw_limit_nm = YAW_DEMAND_SHARE * (self.f_max_n - self.f_min_n) / np.max(np.abs(inverse[:, 3]))
        self.params = np.concatenate([inverse[:, 0], inverse[:, 1], inverse[:, 2], inverse[:, 3],
                                      [self.f_min_n, self.f_max_n, self.k_eta, self.yaw_limit_nm]]).astype(np.float64)

    def _run(self, thrust_n, moments_nm):
        thrusts, speeds = np.empty(4), np.empty(4)
        bits = rotor_commands(float(thrust_n), float(moments_nm[0]), float(moments_nm[1]), float(moments_nm[2]),
                              self.params, thrusts, speeds)
        return thrusts.tolist(), speeds.tolist(), flag_names(bits)

    def rotor_speeds(self, thrust_n, moments_nm):
        """(rotor speed commands (4 floats, rad/s), reduced axes)."""
        _, speeds, flags = self._run(thrust_n, moments_nm)
        return speeds, flags

    def wrench(self, rotor_speeds_radps) -> np.ndarray:
        """[T, Mx, My, Mz] produced by the given rotor speeds (the inverse of rotor_speeds)."""
        w = np.asarray(rotor_speeds_radps, dtype=float)
        return self.allocation @ (self.k_eta * w * np.abs(w))
