"""Newton-Euler quadrotor with rotor speed states, integrated by classical RK4.

State x (17 floats): position (3, world ENU), velocity (3, world), quaternion (x, y, z, w; body FLU ->
world), body rates (3, FLU), rotor speeds (4, rad/s).

    p' = v
    v' = (R(q) (T e3 + F_aero_body) + F_ext_world) / m - g e3,      T = sum k_eta w_i |w_i|
    q' = 1/2 q (x) (omega, 0)
    I omega' = M - omega x I omega,                                  M = A[1:] (k_eta w_i |w_i|)
    w_i' = (w_cmd_i - w_i) / tau_m                                   (w = w_cmd when tau_m = 0)

Aerodynamics (optional), with v_b = R^T (v - wind): body drag F = -c_D (.) |v_b| (.) v_b and rotor
drag F = -(sum w_i) diag(k_d, k_d, k_z) v_b (rotorpy's model). The quaternion is renormalised after
every step. `derivative_into` and `rk4_step` are the compiled kernels (quad_common.compiled) on a
parameter vector; the RigidBody methods wrap them.
"""

from dataclasses import dataclass

import numpy as np

from quad_common.compiled import float_array, njit
from quad_common.types import GRAVITY_MPS2
from quad_common.vehicle import Vehicle

STATE_SIZE = 17
POSITION, VELOCITY, QUATERNION, BODY_RATES, ROTORS = slice(0, 3), slice(3, 6), slice(6, 10), slice(10, 13), \
    slice(13, 17)
# parameter vector: mass, inertia diagonal, k_eta, tau_m, per-rotor moment per w|w| about x, y, z (4 each),
# drag on (0/1), body drag (3), rotor drag xy, z
MASS, IXX, IYY, IZZ, K_ETA, TAU, MOM_X, MOM_Y, MOM_Z, DRAG_ON, BODY_DRAG, ROTOR_DRAG_XY, ROTOR_DRAG_Z = (
    0, 1, 2, 3, 4, 5, 6, 10, 14, 18, 19, 22, 23)
PARAMS_SIZE = 24
NO_FORCE = np.zeros(3)


@dataclass(frozen=True)
class Aerodynamics:
    """Drag coefficients: body drag N/(m/s)^2 per body axis, rotor drag N/(m/s)/(rad/s)."""

    body_drag: tuple = (0.0, 0.0, 0.0)
    rotor_drag_xy: float = 0.0
    rotor_drag_z: float = 0.0

    @property
    def active(self) -> bool:
        return any(self.body_drag) or bool(self.rotor_drag_xy) or bool(self.rotor_drag_z)


@njit
def derivative_into(x, w_cmd, force_world, wind_world, p, out):
    """x' of the model above into `out` (17), holding rotor commands w_cmd, force and wind (world)."""
    vx, vy, vz, qx, qy, qz, qw, pr, qr, rr = x[3], x[4], x[5], x[6], x[7], x[8], x[9], x[10], x[11], x[12]
    w0, w1, w2, w3 = x[13], x[14], x[15], x[16]
    s0, s1, s2, s3 = w0 * abs(w0), w1 * abs(w1), w2 * abs(w2), w3 * abs(w3)
    m = p[MASS]
    fz_b = p[K_ETA] * (s0 + s1 + s2 + s3)
    r13, r23, r33 = 2 * (qx * qz + qy * qw), 2 * (qy * qz - qx * qw), 1 - 2 * (qx * qx + qy * qy)
    if p[DRAG_ON] == 0.0:
        ax = (r13 * fz_b + force_world[0]) / m
        ay = (r23 * fz_b + force_world[1]) / m
        az = (r33 * fz_b + force_world[2]) / m - GRAVITY_MPS2
    else:
        r11, r12 = 1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw)
        r21, r22 = 2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz)
        r31, r32 = 2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw)
        ux, uy, uz = vx - wind_world[0], vy - wind_world[1], vz - wind_world[2]
        bx, by, bz = r11 * ux + r21 * uy + r31 * uz, r12 * ux + r22 * uy + r32 * uz, r13 * ux + r23 * uy + r33 * uz
        cx, cy, cz = p[BODY_DRAG], p[BODY_DRAG + 1], p[BODY_DRAG + 2]
        wsum = abs(w0) + abs(w1) + abs(w2) + abs(w3)
        fx_b = -cx * abs(bx) * bx - p[ROTOR_DRAG_XY] * wsum * bx
        fy_b = -cy * abs(by) * by - p[ROTOR_DRAG_XY] * wsum * by
        fz_b += -cz * abs(bz) * bz - p[ROTOR_DRAG_Z] * wsum * bz
        ax = (r11 * fx_b + r12 * fy_b + r13 * fz_b + force_world[0]) / m
        ay = (r21 * fx_b + r22 * fy_b + r23 * fz_b + force_world[1]) / m
        az = (r31 * fx_b + r32 * fy_b + r33 * fz_b + force_world[2]) / m - GRAVITY_MPS2
    mom_x = p[MOM_X] * s0 + p[MOM_X + 1] * s1 + p[MOM_X + 2] * s2 + p[MOM_X + 3] * s3
    mom_y = p[MOM_Y] * s0 + p[MOM_Y + 1] * s1 + p[MOM_Y + 2] * s2 + p[MOM_Y + 3] * s3
    mom_z = p[MOM_Z] * s0 + p[MOM_Z + 1] * s1 + p[MOM_Z + 2] * s2 + p[MOM_Z + 3] * s3
    ixx, iyy, izz = p[IXX], p[IYY], p[IZZ]
    out[0], out[1], out[2], out[3], out[4], out[5] = vx, vy, vz, ax, ay, az
    out[6] = 0.5 * (qw * pr + qy * rr - qz * qr)
    out[7] = 0.5 * (qw * qr - qx * rr + qz * pr)
    out[8] = 0.5 * (qw * rr + qx * qr - qy * pr)
    out[9] = -0.5 * (qx * pr + qy * qr + qz * rr)
    out[10] = (mom_x + (iyy - izz) * qr * rr) / ixx
    out[11] = (mom_y + (izz - ixx) * rr * pr) / iyy
    out[12] = (mom_z + (ixx - iyy) * pr * qr) / izz
    tau = p[TAU]
    for i in range(4):
        out[13 + i] = (w_cmd[i] - x[13 + i]) / tau if tau > 0.0 else 0.0


@njit
def rk4_step(x, w_cmd, dt_s, force_world, wind_world, p):
    """One RK4 step of dt_s on x (17, in place) holding w_cmd, force and wind; the quaternion kept unit."""
    if p[TAU] <= 0.0:
        for i in range(4):
            x[13 + i] = w_cmd[i]
    h = 0.5 * dt_s
    k1, k2, k3, k4, y = np.empty(17), np.empty(17), np.empty(17), np.empty(17), np.empty(17)
    derivative_into(x, w_cmd, force_world, wind_world, p, k1)
    for i in range(17):
        y[i] = x[i] + h * k1[i]
    derivative_into(y, w_cmd, force_world, wind_world, p, k2)
    for i in range(17):
        y[i] = x[i] + h * k2[i]
    derivative_into(y, w_cmd, force_world, wind_world, p, k3)
    for i in range(17):
        y[i] = x[i] + dt_s * k3[i]
    derivative_into(y, w_cmd, force_world, wind_world, p, k4)
    c = dt_s / 6.0
    for i in range(17):
        x[i] = x[i] + c * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i])
    n = (x[6] * x[6] + x[7] * x[7] + x[8] * x[8] + x[9] * x[9]) ** -0.5
    for i in range(6, 10):
        x[i] *= n


class RigidBody:
    def __init__(self, vehicle: Vehicle, aerodynamics: Aerodynamics | None = None):
        positions, directions = vehicle.rotor_geometry()
        self.mass_kg = vehicle.plant_mass_kg
        self.ixx, self.iyy, self.izz = map(float, vehicle.inertia_kgm2)
        self.k_eta = vehicle.k_eta
        self.tau_m_s = vehicle.motor_time_constant_s
        self.aero = aerodynamics if aerodynamics is not None and aerodynamics.active else None
        aero = self.aero or Aerodynamics()
        p = np.zeros(PARAMS_SIZE)
        p[[MASS, IXX, IYY, IZZ, K_ETA, TAU]] = self.mass_kg, self.ixx, self.iyy, self.izz, self.k_eta, self.tau_m_s
        p[MOM_X:MOM_X + 4] = vehicle.k_eta * positions[:, 1]  # moment per (w |w|) of each rotor about x, y, z
        p[MOM_Y:MOM_Y + 4] = -vehicle.k_eta * positions[:, 0]
        p[MOM_Z:MOM_Z + 4] = -directions * vehicle.k_m
        p[DRAG_ON] = float(self.aero is not None)
        p[BODY_DRAG:BODY_DRAG + 3] = aero.body_drag
        p[ROTOR_DRAG_XY], p[ROTOR_DRAG_Z] = aero.rotor_drag_xy, aero.rotor_drag_z
        self.params = p

    def thrust_n(self, x) -> float:
        return self.k_eta * sum(w * abs(w) for w in x[13:17])

    def derivative(self, x, w_cmd, force_world=(0.0, 0.0, 0.0), wind_world=(0.0, 0.0, 0.0)) -> tuple:
        out = np.empty(STATE_SIZE)
        derivative_into(float_array(x), float_array(w_cmd), float_array(force_world), float_array(wind_world),
                        self.params, out)
        return tuple(out.tolist())

    def step(self, x, w_cmd, dt_s, force_world=(0.0, 0.0, 0.0), wind_world=(0.0, 0.0, 0.0)) -> list:
        """One RK4 step of dt_s holding w_cmd, force and wind; returns the new state (quaternion unit)."""
        y = np.array(x, dtype=np.float64)
        rk4_step(y, float_array(w_cmd), float(dt_s), float_array(force_world), float_array(wind_world), self.params)
        return y.tolist()
