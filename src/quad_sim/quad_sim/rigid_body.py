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
every step. Written with scalar floats: for 17 states that is several times faster than numpy.
"""

from dataclasses import dataclass

from quad_common.types import GRAVITY_MPS2
from quad_common.vehicle import Vehicle

STATE_SIZE = 17
POSITION, VELOCITY, QUATERNION, BODY_RATES, ROTORS = slice(0, 3), slice(3, 6), slice(6, 10), slice(10, 13), \
    slice(13, 17)


@dataclass(frozen=True)
class Aerodynamics:
    """Drag coefficients: body drag N/(m/s)^2 per body axis, rotor drag N/(m/s)/(rad/s)."""

    body_drag: tuple = (0.0, 0.0, 0.0)
    rotor_drag_xy: float = 0.0
    rotor_drag_z: float = 0.0

    @property
    def active(self) -> bool:
        return any(self.body_drag) or bool(self.rotor_drag_xy) or bool(self.rotor_drag_z)


class RigidBody:
    def __init__(self, vehicle: Vehicle, aerodynamics: Aerodynamics | None = None):
        positions, directions = vehicle.rotor_geometry()
        self.mass_kg = vehicle.mass_kg
        self.ixx, self.iyy, self.izz = map(float, vehicle.inertia_kgm2)
        self.k_eta = vehicle.k_eta
        self.tau_m_s = vehicle.motor_time_constant_s
        # moment per (w |w|) of each rotor about x, y, z
        self._mx = tuple(float(vehicle.k_eta * y) for y in positions[:, 1])
        self._my = tuple(float(-vehicle.k_eta * x) for x in positions[:, 0])
        self._mz = tuple(float(-d * vehicle.k_m) for d in directions)
        self.aero = aerodynamics if aerodynamics is not None and aerodynamics.active else None

    def thrust_n(self, x) -> float:
        return self.k_eta * sum(w * abs(w) for w in x[13:17])

    def derivative(self, x, w_cmd, force_world=(0.0, 0.0, 0.0), wind_world=(0.0, 0.0, 0.0)):
        _, _, _, vx, vy, vz, qx, qy, qz, qw, p, q, r, w0, w1, w2, w3 = x
        s0, s1, s2, s3 = w0 * abs(w0), w1 * abs(w1), w2 * abs(w2), w3 * abs(w3)
        mx, my, mz = self._mx, self._my, self._mz
        m = self.mass_kg
        fz_b = self.k_eta * (s0 + s1 + s2 + s3)
        r13, r23, r33 = 2 * (qx * qz + qy * qw), 2 * (qy * qz - qx * qw), 1 - 2 * (qx * qx + qy * qy)
        if self.aero is None:
            ax = (r13 * fz_b + force_world[0]) / m
            ay = (r23 * fz_b + force_world[1]) / m
            az = (r33 * fz_b + force_world[2]) / m - GRAVITY_MPS2
        else:
            r11, r12 = 1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw)
            r21, r22 = 2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz)
            r31, r32 = 2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw)
            ux, uy, uz = vx - wind_world[0], vy - wind_world[1], vz - wind_world[2]
            bx, by, bz = r11 * ux + r21 * uy + r31 * uz, r12 * ux + r22 * uy + r32 * uz, r13 * ux + r23 * uy + r33 * uz
            (cx, cy, cz), wsum = self.aero.body_drag, abs(w0) + abs(w1) + abs(w2) + abs(w3)
            fx_b = -cx * abs(bx) * bx - self.aero.rotor_drag_xy * wsum * bx
            fy_b = -cy * abs(by) * by - self.aero.rotor_drag_xy * wsum * by
            fz_b += -cz * abs(bz) * bz - self.aero.rotor_drag_z * wsum * bz
            ax = (r11 * fx_b + r12 * fy_b + r13 * fz_b + force_world[0]) / m
            ay = (r21 * fx_b + r22 * fy_b + r23 * fz_b + force_world[1]) / m
            az = (r31 * fx_b + r32 * fy_b + r33 * fz_b + force_world[2]) / m - GRAVITY_MPS2
        mom_x = mx[0] * s0 + mx[1] * s1 + mx[2] * s2 + mx[3] * s3
        mom_y = my[0] * s0 + my[1] * s1 + my[2] * s2 + my[3] * s3
        mom_z = mz[0] * s0 + mz[1] * s1 + mz[2] * s2 + mz[3] * s3
        ixx, iyy, izz = self.ixx, self.iyy, self.izz
        tau = self.tau_m_s
        if tau > 0.0:
            c0, c1, c2, c3 = w_cmd
            dw = ((c0 - w0) / tau, (c1 - w1) / tau, (c2 - w2) / tau, (c3 - w3) / tau)
        else:
            dw = (0.0, 0.0, 0.0, 0.0)
        return (vx, vy, vz, ax, ay, az,
                0.5 * (qw * p + qy * r - qz * q), 0.5 * (qw * q - qx * r + qz * p),
                0.5 * (qw * r + qx * q - qy * p), -0.5 * (qx * p + qy * q + qz * r),
                (mom_x + (iyy - izz) * q * r) / ixx, (mom_y + (izz - ixx) * r * p) / iyy,
                (mom_z + (ixx - iyy) * p * q) / izz) + dw

    def step(self, x, w_cmd, dt_s, force_world=(0.0, 0.0, 0.0), wind_world=(0.0, 0.0, 0.0)) -> list:
        """One RK4 step of dt_s holding w_cmd, force and wind; returns the new state (quaternion unit)."""
        if self.tau_m_s <= 0.0:
            x = list(x[:13]) + list(w_cmd)
        f, h = self.derivative, 0.5 * dt_s
        k1 = f(x, w_cmd, force_world, wind_world)
        k2 = f([a + h * b for a, b in zip(x, k1)], w_cmd, force_world, wind_world)
        k3 = f([a + h * b for a, b in zip(x, k2)], w_cmd, force_world, wind_world)
        k4 = f([a + dt_s * b for a, b in zip(x, k3)], w_cmd, force_world, wind_world)
        c = dt_s / 6.0
        out = [a + c * (b1 + 2.0 * (b2 + b3) + b4) for a, b1, b2, b3, b4 in zip(x, k1, k2, k3, k4)]
        n = (out[6] * out[6] + out[7] * out[7] + out[8] * out[8] + out[9] * out[9]) ** -0.5
        out[6] *= n
        out[7] *= n
        out[8] *= n
        out[9] *= n
        return out
