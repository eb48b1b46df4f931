"""Controllers written by users: our plugin interface, the adapter for flightsim / rotorpy controllers, the one
place a controller name is resolved (`make_controller`), and the guard that turns a failing user controller into
a dead one (docs/plugins.md).

Names (quad_control.controller_names): `pd`, `pid`, `se3` (ours, quad_control.position), `package.module:Class`,
or the name of an entry point of the group `quadflight.controllers` (an installed package registering its classes).

A class is flown one of two ways:
- ours: a subclass of `ControllerPlugin`, built `Class(vehicle, params)` (quad_common.vehicle.Vehicle and the
  rotorpy-style parameter dict of `vehicle_params`), `update(state, reference, dt_s) -> AttitudeSetpoint` in our
  types (world ENU, body FLU, quaternions (x, y, z, w) body -> world, specific force = thrust / mass).
- flightsim / rotorpy (any other class): built `Class(params)`, `update(t, state, flat_output) -> dict`. Its world
  frame is z up and its body frame x forward, z along the thrust, its quaternions (x, y, z, w) body -> world
  (scipy's): ours, so the conversion renames fields only. `cmd_thrust` (N) / mass becomes the specific force,
  `cmd_q` the attitude; `cmd_w` is not flown (rotorpy's SE3Control fills it with its own attitude PD's output, a
  feedback: as a feed-forward on top of the vehicle's attitude loop it would double that loop's gain). A result
  with only `cmd_motor_speeds` / `cmd_moment` is refused: the attitude loop is the vehicle's (the simulator's
  onboard loop, the autopilot's through the bridge).

Whatever the class returns is checked every tick (keys, shapes, finite, a non-zero quaternion) and clamped to the
vehicle's thrust range and tilt like ours. An exception, a bad result or an update slower than the tick raises
ControllerFailed naming the class and the line. Slower than the tick: over the period on LATE_TICKS updates in a
row (a one-off, a garbage collection or a preemption of a busy machine, is not), in its thread's CPU time (it
cannot keep up on this machine) or, in real time (`wall_clock`: a real vehicle, a realtime simulator), in wall time
(a blocking call); a lockstep or offline flight waits for it, so there only CPU time counts.
quad_control.loop then treats the controller as dead (no setpoint is published again: the simulator's and the
bridge's setpoint-timeout failsafes take the vehicle).
"""

import inspect
import math
import time

import numpy as np

from quad_common import rotations
from quad_common.types import AttitudeSetpoint, Reference, State
from quad_common.user_code import user_line
from quad_common.vehicle import Vehicle
from quad_control.controller_names import CONTROLLERS, ControllerRefused, resolve
from quad_control.position import (
    Limits,
    PositionController,
    PositionGains,
    Saturation,
    clamp_thrust,
)

MOTOR_LEVEL_KEYS = ('cmd_motor_speeds', 'cmd_motor_thrusts', 'cmd_moment')
LATE_TICKS = 3   # over the period on this many updates in a row is too slow


class ControllerFailed(ValueError):
    """A user controller failed at run time; the loop treats it as dead from then on."""


class ControllerPlugin:
    """Base class of a controller in our types. Built with the vehicle and its rotorpy-style parameters; keep any
    state on self and clear it in reset() (called when a plan starts and at a hand-over's engagement).
    self.gains: position_controller's gains (PositionGains: kp, kd, ki per axis, ... of the control profile, a sweep
    entry or tune's search), kept current before every update, for a class that wants them."""

    def __init__(self, vehicle: Vehicle, params: dict):
        self.vehicle = vehicle
        self.params = params
        self.gains = PositionGains()

    def reset(self):
        pass

    def update(self, state: State, reference: Reference, dt_s: float) -> AttitudeSetpoint:
        raise NotImplementedError


def vehicle_params(vehicle: Vehicle) -> dict:
    """The vehicle as rotorpy's vehicles/crazyflie_params.py (and the course's quad_params) name it.

    rotorpy's rotor_directions give the sign of each rotor's yaw moment (+1: +z), ours the spin (+1 CCW, moment
    -k_m w^2): they are negated here, so an allocator written for rotorpy gets this vehicle's moments right."""
    positions, spins = vehicle.rotor_geometry()
    aero = vehicle.extra.get('aerodynamics') or {}
    body_drag = list(aero.get('body_drag', [0.0, 0.0, 0.0]))
    kp, kd = vehicle.effective_attitude_gains()
    return {
        'mass': vehicle.mass_kg, 'Ixx': float(vehicle.inertia_kgm2[0]), 'Iyy': float(vehicle.inertia_kgm2[1]),
        'Izz': float(vehicle.inertia_kgm2[2]), 'Ixy': 0.0, 'Iyz': 0.0, 'Ixz': 0.0,
        'num_rotors': 4, 'rotor_pos': {f'r{i + 1}': positions[i].copy() for i in range(4)},
        'rotor_directions': -spins, 'rI': np.zeros(3),
        'c_Dx': float(body_drag[0]), 'c_Dy': float(body_drag[1]), 'c_Dz': float(body_drag[2]),
        'k_eta': vehicle.k_eta, 'k_m': vehicle.k_m, 'k_d': float(aero.get('rotor_drag_xy', 0.0)),
        'k_z': float(aero.get('rotor_drag_z', 0.0)), 'k_h': 0.0, 'k_flap': 0.0,
        'tau_m': vehicle.motor_time_constant_s, 'rotor_speed_min': vehicle.rotor_speed_min_radps,
        'rotor_speed_max': vehicle.rotor_speed_max_radps, 'motor_noise_std': 0.0,
        'k_w': 1.0, 'k_v': 10.0, 'kp_att': float(kp[0]), 'kd_att': float(kd[0]),
        # the course's (flightsim) names for the same numbers
        'arm_length': vehicle.arm_length_m, 'k_thrust': vehicle.k_eta, 'k_drag': vehicle.k_m,
    }


def state_dict(state: State, hover_rotor_speed_radps: float) -> dict:
    """Our State as rotorpy's state dict (same frames and quaternion order; no wind estimate, rotors at hover)."""
    return {'x': np.array(state.position, dtype=float), 'v': np.array(state.velocity, dtype=float),
            'q': np.array(state.quaternion, dtype=float), 'w': np.array(state.body_rates, dtype=float),
            'wind': np.zeros(3), 'rotor_speeds': np.full(4, hover_rotor_speed_radps)}


def flat_output(ref: Reference) -> dict:
    """Our Reference as rotorpy's flat outputs (our plans carry no snap nor yaw acceleration: zeros)."""
    return {'x': np.array(ref.position, dtype=float), 'x_dot': np.array(ref.velocity, dtype=float),
            'x_ddot': np.array(ref.acceleration, dtype=float), 'x_dddot': np.array(ref.jerk, dtype=float),
            'x_ddddot': np.zeros(3), 'yaw': float(ref.yaw), 'yaw_dot': float(ref.yaw_rate), 'yaw_ddot': 0.0}


def make_controller(name: str, gains: PositionGains | None, vehicle: Vehicle, limits: Limits | None = None,
                    rate_hz: float = 100.0, wall_clock: bool = False):
    """The controller `name` means: our PositionController, or a user class behind PluginController (built and
    probed once on a hover, so a construction error or an unusable result is refused here, before anything
    starts). The one place every path (node, offline loop, fleet loop, replay, identify) builds its controller."""
    if name in CONTROLLERS:
        return PositionController(name, gains or PositionGains(), vehicle, limits)
    return PluginController(name, resolve(name), vehicle, limits, rate_hz=rate_hz, gains=gains, wall_clock=wall_clock)


# --- the guard ----------------------------------------------------------------------------------------------


def _where(method) -> str:
    try:
        return f'{inspect.getsourcefile(method)}:{inspect.getsourcelines(method)[1]}'
    except (TypeError, OSError):
        return '?'


def limit_tilt(quaternion, max_tilt_rad: float) -> tuple[np.ndarray, bool]:
    """The attitude with its body z tilted at most max_tilt_rad from world z (azimuth and heading kept)."""
    rot = rotations.to_matrix(quaternion)
    b3 = rot[:, 2]
    if b3[2] >= math.cos(max_tilt_rad):
        return quaternion, False
    horizontal = math.hypot(b3[0], b3[1])
    s = math.sin(max_tilt_rad)
    b3 = np.array([b3[0] / horizontal * s, b3[1] / horizontal * s, math.cos(max_tilt_rad)]) if horizontal > 0 \
        else np.array([0.0, 0.0, 1.0])
    return rotations.from_body_z_and_yaw(b3, math.atan2(rot[1, 0], rot[0, 0])), True


class PluginController:
    """A user class behind the interface ControlLoop drives (update(state, ref, dt_s) -> (setpoint, Saturation),
    reset(), name, gains, limits): converts, times, checks and clamps each result (module docstring)."""

    def __init__(self, name: str, cls, vehicle: Vehicle, limits: Limits | None = None, rate_hz: float = 100.0,
                 gains: PositionGains | None = None, wall_clock: bool = True):
        self.name, self.cls, self.vehicle = name, cls, vehicle
        self.gains = gains or PositionGains()    # handed to a ControllerPlugin before each update
        self.limits = limits or Limits.of(vehicle)
        self.period_s = 1.0 / float(rate_hz)
        self.wall_clock = wall_clock              # the tick is due in wall time (module docstring)
        self.late_ticks = 0                       # consecutive updates over the period
        self.ours = issubclass(cls, ControllerPlugin)
        self.params = vehicle_params(vehicle)
        self.integral_m_s = np.zeros(3)           # diagnostics' field of ours: a user class has none
        self._hover_radps = math.sqrt(vehicle.hover_thrust_n / (4 * vehicle.k_eta))
        self._where = f'{cls.__module__}.{cls.__qualname__}'
        self._probe()
        self.instance = self._build()
        self.t_s = 0.0

    def _build(self):
        try:
            return self.cls(self.vehicle, dict(self.params)) if self.ours else self.cls(dict(self.params))
        except Exception as exc:  # noqa: BLE001  (user code)
            raise ControllerRefused(f'controller {self.name!r}: building {self._where} failed: '
                                    f'{type(exc).__name__}: {exc}{user_line(exc)}') from None

    def _probe(self):
        """One update of a fresh instance hovering at the origin: a class that raises or whose result is unusable
        (no cmd_thrust / cmd_q, motor speeds only, non-finite) is refused before anything starts."""
        instance = self._build()
        hover = State()
        try:
            self._call(instance, hover, Reference(), 0.0, 0.0, timed=False)   # a first call may warm caches up
        except ControllerFailed as exc:
            raise ControllerRefused(f'controller {self.name!r} refused: {exc}') from None

    def reset(self):
        self.t_s = 0.0
        if self.ours:
            self._guard(self.instance.reset, 'reset')

    def _guard(self, call, what, *args):
        try:
            return call(*args)
        except ControllerFailed:
            raise
        except Exception as exc:  # noqa: BLE001  (user code: anything it raises kills it, never the node)
            raise ControllerFailed(f'{self._where}.{what} raised {type(exc).__name__}: {exc}{user_line(exc)}') \
                from None

    def _call(self, instance, state: State, ref: Reference, t_s: float, dt_s: float,
              timed: bool = True) -> AttitudeSetpoint:
        started, started_cpu = time.perf_counter(), time.thread_time()
        if self.ours:
            instance.gains = self.gains
            result = self._guard(instance.update, 'update', state, ref, dt_s)
        else:
            result = self._guard(instance.update, 'update', t_s, state_dict(state, self._hover_radps),
                                 flat_output(ref))
        took_s, cpu_s = time.perf_counter() - started, time.thread_time() - started_cpu
        if timed:
            late = cpu_s > self.period_s or (self.wall_clock and took_s > self.period_s)
            self.late_ticks = self.late_ticks + 1 if late else 0
            if self.late_ticks >= LATE_TICKS:
                what = f'{1e3 * cpu_s:.1f} ms of CPU' if cpu_s > self.period_s else f'{1e3 * took_s:.1f} ms'
                what += f' ({LATE_TICKS} updates in a row over the tick)'
                raise ControllerFailed(f'{self._where}.update took {what} > the tick {1e3 * self.period_s:.1f} ms '
                                       f'({_where(instance.update)})')
        try:
            return self._setpoint(result, instance)
        except ControllerFailed:
            raise
        except Exception as exc:  # noqa: BLE001  (a result of a shape no check foresaw: refused, never raised on)
            raise self._bad(instance, f'an unusable result {result!r} ({type(exc).__name__}: {exc})') from None

    def _bad(self, instance, what: str):
        return ControllerFailed(f'{self._where}.update returned {what} ({_where(instance.update)})')

    def _setpoint(self, result, instance) -> AttitudeSetpoint:
        if self.ours:
            if not isinstance(result, AttitudeSetpoint):
                raise self._bad(instance, f'{type(result).__name__}, not an AttitudeSetpoint')
            quaternion, force, rates = result.quaternion, result.specific_force_mps2, result.body_rates
        else:
            if not isinstance(result, dict):
                raise self._bad(instance, f'{type(result).__name__}, not a dict')
            missing = [k for k in ('cmd_thrust', 'cmd_q') if k not in result]
            if missing:
                motor = [k for k in MOTOR_LEVEL_KEYS if k in result]
                if motor:
                    raise self._bad(instance, f'{", ".join(motor)} without {" and ".join(missing)}: a motor-level '
                                              'controller cannot fly here, the attitude loop is the vehicle\'s '
                                              '(the autopilot\'s on a real one); return cmd_thrust (N) and cmd_q')
                raise self._bad(instance, f'a dict without {" and ".join(missing)} (keys: {sorted(result)})')
            quaternion, rates = result['cmd_q'], None
            thrust = np.asarray(result['cmd_thrust'], dtype=float) if _numeric(result['cmd_thrust']) else None
            if thrust is None or thrust.size != 1:
                raise self._bad(instance, f'cmd_thrust = {result["cmd_thrust"]!r}, not one number (N)')
            force = float(thrust.reshape(())) / self.vehicle.mass_kg
        quaternion = np.asarray(quaternion, dtype=float) if _numeric(quaternion) else None
        if quaternion is None or quaternion.shape != (4,):
            raise self._bad(instance, f'an attitude {result!r}, not a quaternion (x, y, z, w)')
        norm = float(np.linalg.norm(quaternion))
        if not (math.isfinite(force) and np.isfinite(quaternion).all() and norm > 0.5):
            raise self._bad(instance, f'a non-finite or zero setpoint: thrust/mass {force}, '
                                      f'quaternion {quaternion.tolist()}')
        if rates is not None:
            rates = np.asarray(rates, dtype=float) if _numeric(rates) else None
            if rates is None or rates.shape != (3,) or not np.isfinite(rates).all():
                raise self._bad(instance, f'body_rates {result.body_rates!r}, not three finite numbers')
        return AttitudeSetpoint(quaternion=quaternion / norm, specific_force_mps2=float(force), body_rates=rates)

    def update(self, state: State, ref: Reference, dt_s: float) -> tuple[AttitudeSetpoint, Saturation]:
        if not math.isfinite(dt_s) or dt_s < 0:
            raise ValueError(f'dt_s = {dt_s} must be finite and >= 0')
        self.t_s += dt_s
        setpoint = self._call(self.instance, state, ref, self.t_s, dt_s)
        sat = Saturation()
        mass = self.vehicle.mass_kg
        thrust_n = clamp_thrust(setpoint.specific_force_mps2 * mass, self.limits, sat)
        setpoint.specific_force_mps2 = thrust_n / mass / self.gains.thrust_scale
        setpoint.quaternion, sat.tilt = limit_tilt(setpoint.quaternion, self.limits.max_tilt_rad)
        return setpoint, sat


def _numeric(value) -> bool:
    try:
        return np.asarray(value).dtype.kind in 'iuf'
    except (TypeError, ValueError):
        return False
