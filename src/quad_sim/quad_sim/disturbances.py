"""Disturbance profiles (config/disturbances.yaml): drag, wind, gusts, odometry noise and latency.

Every effect is off in the profile `none`, the deterministic default. A profile is a mapping:

    body_drag: true            # use the vehicle's aerodynamics.body_drag coefficients
    rotor_drag: true           # use the vehicle's aerodynamics.rotor_drag_xy / rotor_drag_z
    wind_mps: [1.0, 0.0, 0.0]  # constant wind, world ENU
    gusts: {std_mps: [0.3, 0.3, 0.1], length_scale_m: 2.0, airspeed_mps: 1.0}
    odom_noise: {position_std_m: 0.002, velocity_std_mps: 0.01, attitude_std_rad: 0.002,
                 body_rates_std_radps: 0.01}
    odom_latency_s: 0.01

Gusts follow the Dryden model's first-order (longitudinal) shaping filter per axis: a Gauss-Markov
process with correlation time L / V and standard deviation sigma, discretised exactly:
    g_{k+1} = a g_k + sigma sqrt(1 - a^2) n_k,   a = exp(-dt V / L),   n_k ~ N(0, 1) from the seed.
"""

import math
from dataclasses import dataclass, field

import numpy as np

from quad_sim.disturbance_file import profile_entry

NOISE_KEYS = ('position_std_m', 'velocity_std_mps', 'attitude_std_rad', 'body_rates_std_radps')
PROFILE_KEYS = ('body_drag', 'rotor_drag', 'wind_mps', 'gusts', 'odom_noise', 'odom_latency_s')


@dataclass
class DisturbanceProfile:
    name: str = 'none'
    body_drag: bool = False
    rotor_drag: bool = False
    wind_mps: np.ndarray = field(default_factory=lambda: np.zeros(3))
    gust_std_mps: np.ndarray = field(default_factory=lambda: np.zeros(3))
    gust_length_scale_m: float = 1.0
    gust_airspeed_mps: float = 1.0
    odom_noise: dict = field(default_factory=lambda: dict.fromkeys(NOISE_KEYS, 0.0))
    odom_latency_s: float = 0.0

    @property
    def has_gusts(self) -> bool:
        return bool(np.any(self.gust_std_mps > 0))

    @property
    def has_odom_noise(self) -> bool:
        return any(v > 0 for v in self.odom_noise.values())

    def aerodynamics(self, vehicle):
        """The vehicle's drag coefficients for the effects this profile switches on (a rigid_body.Aerodynamics)."""
        return vehicle_aerodynamics(vehicle, body=self.body_drag, rotor=self.rotor_drag)


def _nonneg(value, where, n=None):
    arr = np.asarray(value, dtype=float) if isinstance(value, (int, float, list, tuple)) else None
    if arr is None or isinstance(value, bool) or (n is not None and arr.shape != (n,)) or \
            (n is None and arr.shape != ()) or not np.all(np.isfinite(arr)):
        shape = f'{n} finite numbers' if n else 'a finite number'
        raise ValueError(f'{where} = {value!r} must be {shape}')
    return arr


def profile_from_dict(data, name='profile') -> DisturbanceProfile:
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ValueError(f'disturbance profile {name} must be a mapping, got {data!r}')
    unknown = set(data) - set(PROFILE_KEYS)
    if unknown:
        raise ValueError(f'disturbance profile {name}: unknown key(s) {sorted(unknown)}; known: {PROFILE_KEYS}')
    p = DisturbanceProfile(name=name)
    for key in ('body_drag', 'rotor_drag'):
        if not isinstance(data.get(key, False), bool):
            raise ValueError(f'{name}.{key} = {data[key]!r} must be true or false')
        setattr(p, key, data.get(key, False))
    p.wind_mps = _nonneg(data.get('wind_mps', [0.0, 0.0, 0.0]), f'{name}.wind_mps', 3)
    gusts = data.get('gusts') or {}
    if not isinstance(gusts, dict):
        raise ValueError(f'{name}.gusts = {gusts!r} must be a mapping (std_mps, length_scale_m, airspeed_mps)')
    p.gust_std_mps = _nonneg(gusts.get('std_mps', [0.0, 0.0, 0.0]), f'{name}.gusts.std_mps', 3)
    p.gust_length_scale_m = float(_nonneg(gusts.get('length_scale_m', 1.0), f'{name}.gusts.length_scale_m'))
    p.gust_airspeed_mps = float(_nonneg(gusts.get('airspeed_mps', 1.0), f'{name}.gusts.airspeed_mps'))
    noise = data.get('odom_noise') or {}
    if not isinstance(noise, dict) or set(noise) - set(NOISE_KEYS):
        raise ValueError(f'{name}.odom_noise = {noise!r} must be a mapping with keys from {NOISE_KEYS}')
    p.odom_noise = {k: float(_nonneg(noise.get(k, 0.0), f'{name}.odom_noise.{k}')) for k in NOISE_KEYS}
    p.odom_latency_s = float(_nonneg(data.get('odom_latency_s', 0.0), f'{name}.odom_latency_s'))
    negative = [k for k in ('gust_std_mps', 'gust_length_scale_m', 'gust_airspeed_mps', 'odom_latency_s')
                if np.any(np.asarray(getattr(p, k)) < 0)] + [k for k, v in p.odom_noise.items() if v < 0]
    if negative or p.gust_length_scale_m <= 0 or p.gust_airspeed_mps <= 0:
        raise ValueError(f'disturbance profile {name}: {negative or "gusts length/airspeed"} must be positive')
    return p


def load_profile(path, name: str) -> DisturbanceProfile:
    """Profile `name` from a disturbances YAML file (`none` always exists: quad_sim.disturbance_file)."""
    return profile_from_dict(profile_entry(path, name), name)


def vehicle_aerodynamics(vehicle, body=True, rotor=True):
    """Drag coefficients from the vehicle file's `aerodynamics:` section (zero where absent), a
    rigid_body.Aerodynamics (imported here: fly checks a profile's name and fields without the compiled dynamics)."""
    from quad_sim.rigid_body import Aerodynamics

    aero = vehicle.extra.get('aerodynamics') or {}
    where = f'{vehicle.name}: aerodynamics'
    body_drag = _nonneg(aero.get('body_drag', [0.0, 0.0, 0.0]), f'{where}.body_drag', 3)
    rotor_xy = float(_nonneg(aero.get('rotor_drag_xy', 0.0), f'{where}.rotor_drag_xy'))
    rotor_z = float(_nonneg(aero.get('rotor_drag_z', 0.0), f'{where}.rotor_drag_z'))
    if np.any(body_drag < 0) or rotor_xy < 0 or rotor_z < 0:
        raise ValueError(f'{where}: drag coefficients must be >= 0')
    return Aerodynamics(body_drag=tuple(map(float, body_drag)) if body else (0.0, 0.0, 0.0),
                        rotor_drag_xy=rotor_xy if rotor else 0.0, rotor_drag_z=rotor_z if rotor else 0.0)


class Gusts:
    """Per-axis Dryden-type gust velocity (world frame), advanced once per physics step."""

    def __init__(self, profile: DisturbanceProfile, dt_s: float, rng: np.random.Generator):
        self.a = math.exp(-dt_s * profile.gust_airspeed_mps / profile.gust_length_scale_m)
        self.gain = profile.gust_std_mps * math.sqrt(1.0 - self.a * self.a)
        self.rng = rng
        self.velocity_mps = np.zeros(3)

    def step(self) -> np.ndarray:
        self.velocity_mps = self.a * self.velocity_mps + self.gain * self.rng.standard_normal(3)
        return self.velocity_mps
