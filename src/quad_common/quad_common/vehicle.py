"""The vehicle description shared by planner (limits), controller (mass, thrust, tilt) and simulator.

Loaded from config/vehicles/*.yaml; every field is checked and a bad one is named.
Rotor model: thrust_i = k_eta w_i^2 along body z, yaw moment_i = -dir_i k_m w_i^2 (dir +1 = CCW).
"""

from dataclasses import dataclass, field

import numpy as np

from quad_common.types import GRAVITY_MPS2
from quad_common.yaml_io import load_yaml


@dataclass
class AttitudeGains:
    """The seed's equation 6 gains (per roll, pitch, yaw axis)."""

    kp: np.ndarray = field(default_factory=lambda: np.array([3000.0, 3000.0, 3000.0]))
    kd: np.ndarray = field(default_factory=lambda: np.array([300.0, 300.0, 300.0]))


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
    extra: dict = field(default_factory=dict)  # model-specific fields (drag, ...) owned by their users

    @property
    def inertia_matrix(self) -> np.ndarray:
        return np.diag(self.inertia_kgm2)

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


def vehicle_from_dict(data: dict, path='vehicle') -> Vehicle:
    inertia = data.get('inertia_kgm2')
    if (not isinstance(inertia, (list, tuple)) or len(inertia) != 3
            or not all(isinstance(v, (int, float)) and np.isfinite(v) and v > 0 for v in inertia)):
        raise ValueError(f'{path}: inertia_kgm2 = {inertia!r} must be three finite numbers > 0 (Ixx, Iyy, Izz)')
    gains = data.get('attitude_gains', {})
    kp = np.asarray(gains.get('kp', [3000.0] * 3), dtype=float)
    kd = np.asarray(gains.get('kd', [300.0] * 3), dtype=float)
    for name, g in (('kp', kp), ('kd', kd)):
        if g.shape != (3,) or not np.all(np.isfinite(g)) or np.any(g < 0):
            raise ValueError(f'{path}: attitude_gains.{name} = {g.tolist()} must be three finite numbers >= 0')
    layout = data.get('layout', 'x')
    if layout not in ('x', 'plus'):
        raise ValueError(f"{path}: layout = {layout!r} must be 'x' or 'plus'")
    known = {'name', 'mass_kg', 'inertia_kgm2', 'arm_length_m', 'k_eta', 'k_m', 'rotor_speed_min_radps',
             'rotor_speed_max_radps', 'motor_time_constant_s', 'layout', 'max_tilt_deg', 'attitude_gains'}
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


def load_vehicle(path, overrides: dict | None = None) -> Vehicle:
    """The vehicle file, with `overrides` (top-level keys; mappings such as attitude_gains merged one level
    deep) applied before the checks, so a bad override is named like a bad file entry."""
    data = load_yaml(path)
    where = str(path)
    if overrides:
        if not isinstance(overrides, dict):
            raise ValueError(f'{path}: overrides = {overrides!r} must be a mapping of vehicle keys')
        data = dict(data)
        for key, value in overrides.items():
            both_maps = isinstance(value, dict) and isinstance(data.get(key), dict)
            data[key] = {**data[key], **value} if both_maps else value
        where = f'{path} with {overrides}'
    return vehicle_from_dict(data, where)
