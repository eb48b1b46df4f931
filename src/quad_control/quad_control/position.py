"""Position controllers: the seed's cascaded PD (its eq. 1-5), PID (its section 5.1 fix), SE(3).

All three share eq. 1, the desired acceleration per axis i in (x, y, z):

    a_des_i = a_T_i + kd_i (v_T_i - v_i) + kp_i (r_T_i - r_i)  [+ ki_i integral(r_T_i - r_i) dt]

and turn it into an attitude/thrust setpoint for the vehicle's attitude loop:
- `pd`, `pid`: eq. 2-5, the seed's small-angle law
      u1 = m g + m a_des_z
      phi_des   = (a_des_x sin(psi_T) - a_des_y cos(psi_T)) / g
      theta_des = (a_des_x cos(psi_T) + a_des_y sin(psi_T)) / g
      psi_des   = psi_T,   body-rate feed-forward (0, 0, psi_T')
- `se3`: Lee, Leok, McClamroch (2010) / Mellinger, Kumar (2011): b3_des = F/|F| with
  F = m (a_des + g e3), b2 = b3 x c / |b3 x c| with c = (cos psi_T, sin psi_T, 0), thrust F . b3
  (current body z), body-rate feed-forward from the reference jerk j (Mellinger), and r from
  omega_z = -b1 . d(b2)/dt for this b2 construction, with y_c = e3 x c:
      p = -(m / |F|) j . b2,   q = (m / |F|) j . b1,
      r = (p c . b3 + psi_T' y_c . b2) / |b3 x c|
Limits come from the vehicle (thrust range, max tilt); every clamp is reported in `Saturation`.
A non-finite state or reference raises ValueError: no non-finite command is ever produced.
"""

import math
from dataclasses import dataclass, field

import numpy as np

from quad_common import rotations
from quad_common.types import GRAVITY_MPS2, AttitudeSetpoint, Reference, State, all_finite
from quad_common.vehicle import Vehicle
from quad_control.controller_names import CONTROLLERS
from quad_control.drag_estimate import DragEstimate

E3 = np.array([0.0, 0.0, 1.0])


def _axes(values):
    return field(default_factory=lambda: np.array(values, dtype=float))


@dataclass
class PositionGains:
    """Per-axis (x, y, z) gains of eq. 1; the seed's values are the defaults (x and y kept separate)."""

    kp: np.ndarray = _axes([5.0, 5.0, 20.0])    # 1/s^2
    kd: np.ndarray = _axes([5.0, 5.0, 10.0])    # 1/s
    ki: np.ndarray = _axes([2.0, 2.0, 10.0])    # 1/s^3, used by pid only (stable while ki < kp kd)
    integral_limit_mps2: float = 2.0            # anti-windup: |ki_i * integral_i| <= this
    use_feedforward: bool = True                # reference acceleration in eq. 1, jerk in se3 rates
    # Speed extensions (all off by default, so the defaults are the seed's controller; docs "Tuning for speed"):
    attitude_lead_s: float = 0.0                # attitude from a_des + lead * (jerk_T + D a_T) (thrust from a_des)
    disturbance_time_constant_s: float = 0.0    # > 0: subtract the observed external acceleration (filtered)
    drag_feedforward_per_s: float = 0.0         # linear air drag D (1/s): a_des += D v_T, the drag the plan meets
    drag_learning_time_s: float = 0.0           # > 0: D learnt online, horizontally (quad_control.drag_estimate,
    #                                             forgetting time), starting from drag_feedforward_per_s
    velocity_from_position_s: float = 0.0       # > 0: the odometry's velocity follows its position's derivative
    #                                             below 1 / (2 pi tau) (quad_control.velocity_blend, in ControlLoop)
    thrust_scale: float = 1.0                   # delivered / commanded specific force of the vehicle (quadflight
    #                                             identify); the command is divided by it


@dataclass
class Limits:
    thrust_min_n: float
    thrust_max_n: float
    max_tilt_rad: float

    @classmethod
    def of(cls, vehicle: Vehicle, max_tilt_deg: float | None = None) -> 'Limits':
        tilt = vehicle.max_tilt_deg if not max_tilt_deg else max_tilt_deg
        return cls(vehicle.thrust_min_n, vehicle.thrust_max_n, np.deg2rad(tilt))


@dataclass
class Saturation:
    """Which limit clipped this command (reported, never hidden)."""

    thrust: bool = False
    tilt: bool = False
    integral: bool = False

    @property
    def any(self) -> bool:
        return self.thrust or self.tilt or self.integral


def _floats(values) -> list:
    """A vector (or a scalar, for every axis) as Python floats: the per-tick law is scalar arithmetic (a numpy
    operation on a 3-vector costs ~1 us, a float one ~30 ns), each operation the IEEE one numpy does elementwise,
    so the result is the same."""
    kind = type(values)
    if kind is np.ndarray and values.ndim == 1:
        return values.tolist()
    if kind is float or kind is int:   # a gain or drag for every axis: np.ndim costs ~1 us
        return [float(values)] * 3
    if np.ndim(values) == 0:
        return [float(values)] * 3
    return [float(v) for v in values]


def check_finite(state: State, ref: Reference):
    """Raises ValueError naming the first non-finite field of the state or the reference."""
    if all_finite((state.position, state.velocity, state.quaternion, state.body_rates, ref.position, ref.velocity,
                   ref.acceleration, ref.jerk, (ref.yaw, ref.yaw_rate))):
        return
    for owner, obj, names in (('state', state, ('position', 'velocity', 'quaternion', 'body_rates')),
                              ('reference', ref, ('position', 'velocity', 'acceleration', 'jerk', 'yaw',
                                                  'yaw_rate'))):
        for name in names:
            value = np.asarray(getattr(obj, name), dtype=float)
            if not np.all(np.isfinite(value)):
                raise ValueError(f'{owner}.{name} is not finite: {value.tolist()}')


def desired_acceleration(state: State, ref: Reference, gains: PositionGains, integral_m_s=None,
                         drag_per_s=None) -> np.ndarray:
    """Eq. 1 (plus ki * integral of the position error for pid), with the plan's drag D v_T in the feed-forward:
    a vehicle in linear air drag (-D v) needs a_T + D v_T to follow the plan, from the plan alone (outside the
    feedback loop, so it adds no lag to it). drag_per_s: D per axis (default gains.drag_feedforward_per_s)."""
    kp, kd = _floats(gains.kp), _floats(gains.kd)
    r, v = _floats(state.position), _floats(state.velocity)
    r_t, v_t = _floats(ref.position), _floats(ref.velocity)
    acc = [kp[i] * (r_t[i] - r[i]) + kd[i] * (v_t[i] - v[i]) for i in range(3)]
    drag = gains.drag_feedforward_per_s if drag_per_s is None else drag_per_s
    if gains.use_feedforward:
        a_t = _floats(ref.acceleration)
        acc = [acc[i] + a_t[i] for i in range(3)]
        drag = _floats(drag)
        if any(drag):
            acc = [acc[i] + drag[i] * v_t[i] for i in range(3)]
    if integral_m_s is not None:
        ki, integral = _floats(gains.ki), _floats(integral_m_s)
        acc = [acc[i] + ki[i] * integral[i] for i in range(3)]
    return np.array(acc)


def attitude_acceleration(acc_des, ref: Reference, gains: PositionGains, drag_per_s=None) -> np.ndarray:
    """The acceleration the attitude is computed from: a_des + lead * (jerk_T + D a_T).

    The onboard eq. 6 with p_des = q_des = 0 follows an attitude step like kp / (s^2 + kd s + kp), i.e. with
    a lag of about kd / kp (0.1 s with the seed's 3000 / 300): commanding the attitude that the plan needs
    `lead` seconds later cancels it to first order (the thrust magnitude, which has no such lag, is not led).
    What the plan needs is its whole feed-forward a_T + D v_T (drag_per_s: D per axis), whose rate is
    jerk_T + D a_T.
    """
    if not gains.attitude_lead_s:
        return acc_des
    lead = np.asarray(ref.jerk, dtype=float)
    if drag_per_s is not None and np.any(drag_per_s) and gains.use_feedforward:
        lead = lead + drag_per_s * np.asarray(ref.acceleration, dtype=float)
    return acc_des + gains.attitude_lead_s * lead


def clamp_thrust(thrust_n, limits: Limits, sat: Saturation) -> float:
    clamped = float(min(max(thrust_n, limits.thrust_min_n), limits.thrust_max_n))  # np.clip: 5 us on a scalar
    sat.thrust = clamped != thrust_n
    return clamped


def seed_setpoint(acc_des, yaw, yaw_rate, mass_kg: float, limits: Limits,
                  acc_attitude=None) -> tuple[AttitudeSetpoint, Saturation]:
    """Eq. 2-5 (roll/pitch from acc_attitude if given, else acc_des); roll/pitch scaled together so that
    their magnitude stays within the max tilt. Scalar arithmetic; sin, cos and hypot are numpy's (math.hypot
    rounds differently)."""
    sat = Saturation()
    yaw = float(yaw)
    s, c = float(np.sin(yaw)), float(np.cos(yaw))
    ax, ay, _ = _floats(acc_des if acc_attitude is None else acc_attitude)
    roll = (ax * s - ay * c) / GRAVITY_MPS2
    pitch = (ax * c + ay * s) / GRAVITY_MPS2
    tilt = float(np.hypot(roll, pitch))
    if tilt > limits.max_tilt_rad:
        sat.tilt = True
        roll, pitch = roll * limits.max_tilt_rad / tilt, pitch * limits.max_tilt_rad / tilt
    thrust_n = clamp_thrust(mass_kg * GRAVITY_MPS2 + mass_kg * float(acc_des[2]), limits, sat)
    return AttitudeSetpoint(quaternion=rotations.from_euler(roll, pitch, yaw), specific_force_mps2=thrust_n / mass_kg,
                            body_rates=np.array([0.0, 0.0, float(yaw_rate)])), sat


def geometric_setpoint(acc_des, state: State, ref: Reference, mass_kg: float, limits: Limits,
                       use_jerk: bool = True, acc_attitude=None) -> tuple[AttitudeSetpoint, Saturation]:
    """SE(3): desired body z along the desired force (of acc_attitude if given), clipped to the max tilt;
    thrust = m (acc_des + g e3) . current body z; Mellinger rate feed-forward."""
    sat = Saturation()
    thrust_force = mass_kg * (np.asarray(acc_des, dtype=float) + GRAVITY_MPS2 * E3)
    force = mass_kg * (np.asarray(acc_des if acc_attitude is None else acc_attitude, dtype=float) + GRAVITY_MPS2 * E3)
    horizontal = np.hypot(force[0], force[1])
    vertical_min = horizontal / np.tan(limits.max_tilt_rad) if horizontal > 0 else 0.0
    if force[2] < vertical_min:  # too steep, or pointing down: keep the direction's azimuth, limit its tilt
        sat.tilt = True
        if force[2] <= 0:
            force[2] = 1e-3 * mass_kg * GRAVITY_MPS2
        force[:2] *= force[2] * np.tan(limits.max_tilt_rad) / horizontal if horizontal > 0 else 1.0
    b3 = force / np.linalg.norm(force)
    b1_yaw = np.array([np.cos(ref.yaw), np.sin(ref.yaw), 0.0])
    b2 = rotations.hat(b3) @ b1_yaw
    b2_norm = np.linalg.norm(b2)  # >= cos(max tilt) > 0
    b2 /= b2_norm
    b1 = rotations.hat(b2) @ b3
    rot_des = np.column_stack([b1, b2, b3])
    x, y, z, w = state.quaternion  # third column of R(q)
    body_z = np.array([2 * (x * z + y * w), 2 * (y * z - x * w), 1 - 2 * (x * x + y * y)])
    thrust_n = clamp_thrust(float(thrust_force @ body_z), limits, sat)
    rates = np.zeros(3)
    if use_jerk:
        h = mass_kg / np.linalg.norm(force) * np.asarray(ref.jerk, dtype=float)
        rates[:2] = [-h @ b2, h @ b1]
    y_yaw = np.array([-b1_yaw[1], b1_yaw[0], 0.0])
    rates[2] = (rates[0] * (b1_yaw @ b3) + ref.yaw_rate * (y_yaw @ b2)) / b2_norm
    return AttitudeSetpoint(quaternion=rotations.from_matrix(rot_des), specific_force_mps2=thrust_n / mass_kg,
                            body_rates=rates), sat


class PositionController:
    """One of CONTROLLERS by name, holding the pid error integral (reset when a new trajectory starts) and, with
    gains.drag_learning_time_s > 0, the learnt drag (kept across resets: it is the vehicle's)."""

    def __init__(self, name: str, gains: PositionGains, vehicle: Vehicle, limits: Limits | None = None):
        if name not in CONTROLLERS:
            raise ValueError(f'controller = {name!r} must be one of {", ".join(CONTROLLERS)}')
        self.name, self.gains, self.vehicle = name, gains, vehicle
        self.limits = limits or Limits.of(vehicle)
        self.integral_m_s = np.zeros(3)
        self.disturbance_mps2 = np.zeros(3)
        self._previous = None   # (velocity, body z, specific force commanded) of the previous step
        self.drag = None        # DragEstimate while gains.drag_learning_time_s > 0
        self._force_mps2 = None   # specific force commanded at the previous step (delivered, before thrust_scale)

    def reset(self):
        self.integral_m_s = np.zeros(3)
        self.disturbance_mps2 = np.zeros(3)
        self._previous = None
        self._force_mps2 = None
        if self.drag is not None:
            self.drag.restart()

    @property
    def drag_per_s(self) -> np.ndarray:
        """D per axis of the plan's drag feed-forward: the learnt one horizontally while learning, else the gains'."""
        fixed = self.gains.drag_feedforward_per_s
        if self.drag is None:
            return np.full(3, fixed)
        return np.array([self.drag.drag_per_s, self.drag.drag_per_s, fixed])

    def _learn_drag(self, state: State, ref: Reference, dt_s):
        """Feeds the drag estimate (started from drag_feedforward_per_s) with the velocity, the specific force of
        the previous step along the body z now, and the plan's velocity; dropped when learning is switched off."""
        learning_time_s = self.gains.drag_learning_time_s
        if not learning_time_s:
            self.drag = None
            return
        if self.drag is None:
            self.drag = DragEstimate(self.gains.drag_feedforward_per_s, learning_time_s)
        self.drag.learning_time_s = learning_time_s
        if self._force_mps2 is None:
            self.drag.restart()
            return
        body_z = rotations.to_matrix(state.quaternion)[:, 2]
        self.drag.update(state.velocity, self._force_mps2 * body_z, ref.velocity, dt_s)

    def _observe_disturbance(self, state: State, dt_s):
        """External acceleration (drag, wind) seen over the last step, first-order filtered:
        d = (v_k - v_k-1) / dt - (f_k-1 (b3_k-1 + b3_k) / 2 - g e3), the thrust being the commanded one."""
        body_z = rotations.to_matrix(state.quaternion)[:, 2]
        if self._previous is not None and dt_s > 0:
            velocity, previous_z, force_mps2 = self._previous
            raw = (state.velocity - velocity) / dt_s - (force_mps2 * 0.5 * (previous_z + body_z) - GRAVITY_MPS2 * E3)
            tau = self.gains.disturbance_time_constant_s
            self.disturbance_mps2 = self.disturbance_mps2 + dt_s / (tau + dt_s) * (raw - self.disturbance_mps2)
        return body_z

    def _integrate(self, error_m, dt_s) -> bool:
        """Clamp anti-windup: |ki_i I_i| <= integral_limit_mps2; True if the clamp acted."""
        bound = np.full(3, np.inf)
        active = self.gains.ki > 0
        bound[active] = self.gains.integral_limit_mps2 / self.gains.ki[active]
        raw = self.integral_m_s + error_m * dt_s
        self.integral_m_s = np.clip(raw, -bound, bound)
        return bool(np.any(self.integral_m_s != raw))

    def update(self, state: State, ref: Reference, dt_s: float) -> tuple[AttitudeSetpoint, Saturation]:
        """One control step; dt_s is the time since the previous step (integral only)."""
        if not math.isfinite(dt_s) or dt_s < 0:
            raise ValueError(f'dt_s = {dt_s} must be finite and >= 0')
        check_finite(state, ref)
        mass_kg = self.vehicle.mass_kg
        integral, windup = None, False
        if self.name == 'pid':
            windup = self._integrate(np.asarray(ref.position) - state.position, dt_s)
            integral = self.integral_m_s
        self._learn_drag(state, ref, dt_s)
        # the gains' D for every axis unless learning (a scalar: the same products as drag_per_s's vector)
        drag_per_s = self.gains.drag_feedforward_per_s if self.drag is None else self.drag_per_s
        acc = desired_acceleration(state, ref, self.gains, integral, drag_per_s)
        observing = self.gains.disturbance_time_constant_s > 0
        if observing:
            body_z = self._observe_disturbance(state, dt_s)
            acc = acc - self.disturbance_mps2
        acc_attitude = attitude_acceleration(acc, ref, self.gains, drag_per_s)
        if self.name == 'se3':
            sp, sat = geometric_setpoint(acc, state, ref, mass_kg, self.limits, use_jerk=self.gains.use_feedforward,
                                         acc_attitude=acc_attitude)
        else:
            sp, sat = seed_setpoint(acc, ref.yaw, ref.yaw_rate, mass_kg, self.limits, acc_attitude=acc_attitude)
        sat.integral = windup
        if observing:
            self._previous = (np.array(state.velocity, dtype=float), body_z, sp.specific_force_mps2)
        if self.drag is not None:
            self._force_mps2 = sp.specific_force_mps2
        if self.gains.thrust_scale != 1.0:  # what the vehicle delivers is thrust_scale times the command
            sp.specific_force_mps2 = sp.specific_force_mps2 / self.gains.thrust_scale
        return sp, sat
