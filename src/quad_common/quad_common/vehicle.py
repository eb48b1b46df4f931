"""The vehicle description shared by planner (limits), controller (mass, thrust, tilt) and simulator.

Loaded from config/vehicles/*.yaml; every field is checked and a bad one is named.
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
from quad_common.yaml_io import load_yaml, refuse_typos


@dataclass
class AttitudeGains:
    """The seed's equation 6 gains (per roll, pitch, yaw axis)."""

    kp: np.ndarray = field(default_factory=lambda: np.array([3000.0, 3000.0, 3000.0]))
    kd: np.ndarray = field(default_factory=lambda: np.array([300.0, 300.0, 300.0]))


ATTITUDE_LOOPS = ('eq6', 'so3_pd', 'lag')


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


def _positive(data, key, path, allow_zero=False):
    value = data.get(key)
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and np.isfinite(value) and (
        value >= 0 if allow_zero else value > 0)
    if not ok:
        rule = '>= 0' if allow_zero else '> 0'
        raise ValueError(f'{path}: {key} = {value!r} must be a finite number {rule}')
    return float(value)


def _three(data, key, default, path, rule_positive=True):
    value = data.get(key, default)
    g = np.asarray(value if not isinstance(value, (int, float)) else [value] * 3, dtype=object)
    ok = g.shape == (3,) and all(isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)
                                 and (v > 0 if rule_positive else v >= 0) for v in g)
    if not ok:
        raise ValueError(f'{path}: {key} = {value!r} must be three finite numbers {"> 0" if rule_positive else ">= 0"}')
    return np.asarray(g, dtype=float)


def attitude_loop_from_dict(data, path='attitude_loop') -> AttitudeLoop:
    if data is None:
        return AttitudeLoop()
    if not isinstance(data, dict):
        raise ValueError(f'{path} = {data!r} must be a mapping with a type ({", ".join(ATTITUDE_LOOPS)})')
    unknown = set(data) - {'type', 'angle_p', 'rate_p', 'time_constant_s', 'use_feedforward_rates'}
    if unknown:
        raise ValueError(f'{path}: unknown field(s) {sorted(unknown)}')
    kind = data.get('type', 'eq6')
    if kind not in ATTITUDE_LOOPS:
        raise ValueError(f'{path}.type = {kind!r} must be one of {", ".join(ATTITUDE_LOOPS)}')
    default = AttitudeLoop()
    loop = AttitudeLoop(type=kind, angle_p=_three(data, 'angle_p', default.angle_p.tolist(), path),
                        rate_p=_three(data, 'rate_p', default.rate_p.tolist(), path),
                        time_constant_s=_positive(data, 'time_constant_s', path) if 'time_constant_s' in data
                        else default.time_constant_s)
    ff = data.get('use_feedforward_rates', True)
    if not isinstance(ff, bool):
        raise ValueError(f'{path}: use_feedforward_rates = {ff!r} must be true or false')
    loop.use_feedforward_rates = ff
    return loop


def _fraction(data, key, path):
    value = data.get(key, 0.0)
    if not (isinstance(value, (int, float)) and not isinstance(value, bool) and np.isfinite(value)
            and -0.5 <= value <= 1.0):
        raise ValueError(f'{path}: {key} = {value!r} must be a finite fraction in [-0.5, 1.0] (0.06 = +6 %)')
    return float(value)


def vehicle_from_dict(data: dict, path='vehicle') -> Vehicle:
    inertia = data.get('inertia_kgm2')
    if (not isinstance(inertia, (list, tuple)) or len(inertia) != 3
            or not all(isinstance(v, (int, float)) and np.isfinite(v) and v > 0 for v in inertia)):
        raise ValueError(f'{path}: inertia_kgm2 = {inertia!r} must be three finite numbers > 0 (Ixx, Iyy, Izz)')
    gains = data.get('attitude_gains') or {}
    if not isinstance(gains, dict):
        raise ValueError(f'{path}: attitude_gains = {gains!r:.120} must be a mapping (kp, kd)')
    converted = {}
    for name, default in (('kp', 3000.0), ('kd', 300.0)):
        value = gains.get(name, [default] * 3)
        try:
            g = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            g = None
        if g is None or g.shape != (3,) or not np.all(np.isfinite(g)) or np.any(g < 0):
            raise ValueError(f'{path}: attitude_gains.{name} = {value!r:.120} must be three finite numbers >= 0')
        converted[name] = g
    kp, kd = converted['kp'], converted['kd']
    layout = data.get('layout', 'x')
    if layout not in ('x', 'plus'):
        raise ValueError(f"{path}: layout = {layout!r} must be 'x' or 'plus'")
    known = {'name', 'mass_kg', 'inertia_kgm2', 'arm_length_m', 'k_eta', 'k_m', 'rotor_speed_min_radps',
             'rotor_speed_max_radps', 'motor_time_constant_s', 'layout', 'max_tilt_deg', 'attitude_gains',
             'attitude_loop', 'mass_error', 'thrust_error'}
    refuse_typos(data, known | {'aerodynamics', 'completion'}, str(path))   # sections other modules read
    v = Vehicle(
        name=str(data.get('name', path)),
        mass_kg=_positive(data, 'mass_kg', path),
        inertia_kgm2=np.asarray(inertia, dtype=float),
        arm_length_m=_positive(data, 'arm_length_m', path),
        k_eta=_positive(data, 'k_eta', path),
        k_m=_positive(data, 'k_m', path),
        rotor_speed_min_radps=_positive(data, 'rotor_speed_min_radps', path, allow_zero=True),
        rotor_speed_max_radps=_positive(data, 'rotor_speed_max_radps', path),
        motor_time_constant_s=_positive(data, 'motor_time_constant_s', path, allow_zero=True)
        if 'motor_time_constant_s' in data else 0.0,
        layout=layout,
        max_tilt_deg=_positive(data, 'max_tilt_deg', path) if 'max_tilt_deg' in data else 35.0,
        attitude_gains=AttitudeGains(kp=kp, kd=kd),
        attitude_loop=attitude_loop_from_dict(data.get('attitude_loop'), f'{path}: attitude_loop'),
        mass_error=_fraction(data, 'mass_error', path),
        thrust_error=_fraction(data, 'thrust_error', path),
        extra={k: val for k, val in data.items() if k not in known},
    )
    if v.rotor_speed_min_radps >= v.rotor_speed_max_radps:
        raise ValueError(f'{path}: rotor_speed_min_radps = {v.rotor_speed_min_radps} must be below '
                         f'rotor_speed_max_radps = {v.rotor_speed_max_radps}')
    if v.max_tilt_deg >= 90:
        raise ValueError(f'{path}: max_tilt_deg = {v.max_tilt_deg} must be below 90')
    if v.thrust_to_weight <= 1.0:
        raise ValueError(f'{path}: the rotors cannot lift the vehicle: max thrust {v.thrust_max_n:.3f} N '
                         f'<= weight {v.hover_thrust_n:.3f} N')
    return v


PLANT_FIELDS = ('motor_time_constant_s', 'attitude_gains', 'attitude_loop', 'mass_error', 'thrust_error')
PLANT_FAMILY_FILE = 'config/plant_family.yaml'


def load_plant_family(path=None) -> dict:
    """{member name: vehicle-file overrides} of config/plant_family.yaml (or `path`); each member checked."""
    from quad_common.paths import resolve_config
    path = resolve_config(path or PLANT_FAMILY_FILE)
    family = load_yaml(path)
    if not isinstance(family, dict) or not family:
        raise ValueError(f'{path}: must map member names to vehicle-field overrides')
    for name, member in family.items():
        if not isinstance(member, dict):
            raise ValueError(f'{path}: member {name!r} = {member!r} must be a mapping of vehicle fields')
        unknown = set(member) - set(PLANT_FIELDS)
        if unknown:
            raise ValueError(f'{path}: member {name!r} sets {sorted(unknown)}; a member may set only '
                             f'{", ".join(PLANT_FIELDS)}')
    return family


def plant_overrides(plant, family_path=None) -> dict:
    """The vehicle-field overrides of `plant`: a family member's name, a mapping, or None / '' (nothing)."""
    if not plant:
        return {}
    if isinstance(plant, dict):
        unknown = set(plant) - set(PLANT_FIELDS)
        if unknown:
            raise ValueError(f'plant sets {sorted(unknown)}; a plant may set only {", ".join(PLANT_FIELDS)}')
        return plant
    family = load_plant_family(family_path)
    if plant not in family:
        raise ValueError(f'plant = {plant!r} is not a member of the plant family ({", ".join(family)})')
    return family[plant]


def load_vehicle(path, plant=None, family_path=None) -> Vehicle:
    """The vehicle file, with a plant family member (name or overrides mapping) applied when given."""
    data = dict(load_yaml(path))
    overrides = plant_overrides(plant, family_path)
    data.update(overrides)
    where = f'{path} with plant {plant!r}' if overrides else str(path)
    return vehicle_from_dict(data, where)
