"""The vehicle description shared by planner (limits), controller (mass, thrust, tilt) and simulator.

Loaded from config/vehicles/*.yaml; every field is checked and a bad one is named (quad_common.vehicle_file, pure
Python, the rules; here the Vehicle they make).
Rotor model: thrust_i = k_eta w_i^2 along body z, yaw moment_i = -dir_i k_m w_i^2 (dir +1 = CCW).

What varies between real vehicles of one design, and only the simulated plant sees (the controller
keeps flying the nominal numbers):
- `attitude_loop`: the onboard attitude loop (AttitudeLoop): `eq6` (the seed's PD, the default),
  `so3_pd` (an autopilot's cascade: angle P -> body-rate setpoint -> rate P, on the SO(3) error) or
  `lag` (the attitude follows the setpoint through a first-order lag, like ArduPilot's input shaping).
- `mass_error`: the plant's mass is mass_kg (1 + mass_error) (a payload, a bigger battery).
- `thrust_error`: the autopilot's thrust is the commanded one times (1 + thrust_error), what a wrong
  hover-thrust parameter (MOT_THST_HOVER / MPC_THR_HOVER) does to a thrust setpoint.
"""

from dataclasses import dataclass, field

import numpy as np

from quad_common.types import GRAVITY_MPS2
from quad_common.vehicle_file import load_vehicle_fields, vehicle_fields


@dataclass
class AttitudeGains:
    """The seed's equation 6 gains (per roll, pitch, yaw axis)."""

    kp: np.ndarray = field(default_factory=lambda: np.array([3000.0, 3000.0, 3000.0]))
    kd: np.ndarray = field(default_factory=lambda: np.array([300.0, 300.0, 300.0]))



@dataclass
class AttitudeLoop:
    """The onboard attitude loop the simulated autopilot runs (per roll, pitch, yaw axis where 3 numbers).

    eq6:    M = I (kp e_euler + kd (omega_des - omega)), omega_des = (0, 0, r_ff)   (attitude_gains)
    so3_pd: omega_sp = angle_p e_R + omega_ff;  M = I rate_p (omega_sp - omega) + omega x I omega
            (PX4's MC_*_P / MC_*RATE_P structure; per axis a PD with kp = angle_p rate_p, kd = rate_p:
            bandwidth ~ angle_p rad/s when rate_p >> angle_p)
    lag:    the attitude target q_t follows the setpoint, q_t' = log(q_t^-1 q_sp) / time_constant_s
            (ArduPilot's ATC_INPUT_TC shaping), tracked by an SO(3) eq. 6 with attitude_gains,
            the target's own rate fed forward.
    use_feedforward_rates: so3_pd only, the setpoint's roll/pitch rates fed forward too (yaw rate always).
    """

    type: str = 'eq6'
    angle_p: np.ndarray = field(default_factory=lambda: np.array([6.5, 6.5, 2.8]))     # 1/s
    rate_p: np.ndarray = field(default_factory=lambda: np.array([60.0, 60.0, 30.0]))   # 1/s
    time_constant_s: float = 0.15
    use_feedforward_rates: bool = True


@dataclass
class Vehicle:
    name: str
    mass_kg: float
    inertia_kgm2: np.ndarray          # diagonal (Ixx, Iyy, Izz)
    arm_length_m: float
    k_eta: float                      # N / (rad/s)^2
    k_m: float                        # N m / (rad/s)^2
    rotor_speed_min_radps: float
    rotor_speed_max_radps: float
    motor_time_constant_s: float = 0.0
    layout: str = 'x'                 # 'x' or 'plus'
    max_tilt_deg: float = 35.0
    attitude_gains: AttitudeGains = field(default_factory=AttitudeGains)
    attitude_loop: AttitudeLoop = field(default_factory=AttitudeLoop)
    mass_error: float = 0.0           # plant only: true mass = mass_kg (1 + mass_error)
    thrust_error: float = 0.0         # plant only: delivered thrust = commanded (1 + thrust_error)
    extra: dict = field(default_factory=dict)  # model-specific fields (drag, ...) owned by their users

    @property
    def inertia_matrix(self) -> np.ndarray:
        return np.diag(self.inertia_kgm2)

    @property
    def plant_mass_kg(self) -> float:
        return self.mass_kg * (1.0 + self.mass_error)

    def effective_attitude_gains(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-axis (kp, kd) of the linearised onboard loop I phi'' = I (kp e - kd omega) (quad_sim.attitude_poles)."""
        loop = self.attitude_loop
        if loop.type == 'so3_pd':
            return loop.angle_p * loop.rate_p, loop.rate_p.copy()
        return self.attitude_gains.kp.copy(), self.attitude_gains.kd.copy()

    @property
    def thrust_min_n(self) -> float:
        return 4 * self.k_eta * self.rotor_speed_min_radps ** 2

    @property
    def thrust_max_n(self) -> float:
        return 4 * self.k_eta * self.rotor_speed_max_radps ** 2

    @property
    def hover_thrust_n(self) -> float:
        return self.mass_kg * GRAVITY_MPS2

    @property
    def thrust_to_weight(self) -> float:
        return self.thrust_max_n / self.hover_thrust_n

    def rotor_geometry(self):
        """Rotor positions (4, 3) in FLU and spin directions (+1 CCW seen from above)."""
        L = self.arm_length_m
        if self.layout == 'x':
            angles = np.deg2rad([45.0, 135.0, 225.0, 315.0])
        else:
            angles = np.deg2rad([0.0, 90.0, 180.0, 270.0])
        positions = np.stack([L * np.cos(angles), L * np.sin(angles), np.zeros(4)], axis=1)
        return positions, np.array([1.0, -1.0, 1.0, -1.0])


def vehicle_from_dict(data: dict, path='vehicle') -> Vehicle:
    """The Vehicle of a vehicle file's content: its fields checked by quad_common.vehicle_file.vehicle_fields, then
    whether the rotors lift it."""
    return _vehicle(vehicle_fields(data, path), path)


def _vehicle(fields: dict, path) -> Vehicle:
    gains, loop = fields['attitude_gains'], fields['attitude_loop']
    v = Vehicle(**{**fields, 'inertia_kgm2': np.asarray(fields['inertia_kgm2'], dtype=float),
                   'attitude_gains': AttitudeGains(kp=np.asarray(gains['kp']), kd=np.asarray(gains['kd'])),
                   'attitude_loop': AttitudeLoop(**{k: np.asarray(value) if k in ('angle_p', 'rate_p') else value
                                                    for k, value in loop.items()})})
    if v.thrust_to_weight <= 1.0:
        raise ValueError(f'{path}: the rotors cannot lift the vehicle: max thrust {v.thrust_max_n:.3f} N '
                         f'<= weight {v.hover_thrust_n:.3f} N')
    return v


def load_vehicle(path, plant=None, family_path=None) -> Vehicle:
    """The vehicle file, with a plant family member (name or overrides mapping) applied when given."""
    fields, where = load_vehicle_fields(path, plant, family_path)
    return _vehicle(fields, where)
