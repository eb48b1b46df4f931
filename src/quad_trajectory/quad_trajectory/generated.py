"""A user's trajectory class as a plan (docs/plugins.md): a mission's `trajectory.generator: package.module:Class`.

The class has rotorpy's trajectory interface: built `Class(waypoints, **generator_args)` (waypoints: the mission's,
an (N, 3) array, metres, world ENU; `Class(**generator_args)` with `generator_waypoints: false`; a list of numbers
in generator_args is passed as a numpy array), `update(t) -> flat_output` with `x`, `x_dot`, `x_ddot` (3 each) and
`yaw`, `yaw_dot`, `yaw_ddot` (optional, 0 when absent). Its duration: the mission's `trajectory.duration_s`, else
the instance's `duration_s` attribute. It is sampled at SAMPLE_RATE_HZ and made our plan: one quintic Hermite
segment per sample interval (position, velocity and acceleration matched at both ends, as the `trajectory` topic is
read: quad_common.sampled_trajectory), so trajectory_node publishes it, `plan` and `fly` check it against the
vehicle (quad_trajectory.feasibility) and the world, and everything downstream treats it like our plans.
A class that cannot be built or gives a missing, mis-shaped or non-finite sample is refused naming the class, t and
the field (ValueError: one line, exit 2 where a command or node starts). The plan's waypoints are the generated
path's start and end (the class need not pass through the mission's).
"""

import math

import numpy as np

from quad_common.sampled_trajectory import hermite_segment_coefficients
from quad_common.user_code import load_attribute
from quad_trajectory import collision
from quad_trajectory.polynomial import PiecewisePolynomial

SAMPLE_RATE_HZ = 100.0
MAX_SAMPLES = 1_000_000


def resolve(name: str):
    """The class `package.module:Class` names (ValueError naming why not)."""
    if not isinstance(name, str) or ':' not in name:
        raise ValueError(f'trajectory.generator = {name!r} must be package.module:Class')
    cls = load_attribute(name, f'trajectory.generator = {name!r}')
    if not callable(getattr(cls, 'update', None)):
        raise ValueError(f'trajectory.generator = {name!r}: {cls!r} has no update(t) method')
    return cls


def _vector(out: dict, key: str, n: int, where: str, default=None):
    if key not in out:
        if default is not None:
            return default
        raise ValueError(f'{where} has no {key!r} (keys: {sorted(out)})')
    try:
        value = np.asarray(out[key], dtype=float).reshape(-1)
    except (TypeError, ValueError):
        value = None
    if value is None or value.size != n or not np.isfinite(value).all():
        raise ValueError(f'{where}[{key!r}] = {out[key]!r} is not {n} finite number{"s" if n > 1 else ""}')
    return value


def sample(generator, name: str, duration_s: float, rate_hz: float = SAMPLE_RATE_HZ):
    """(t, position (K, 4), velocity (K, 4), acceleration (K, 4)) of generator.update over [0, duration_s]."""
    count = math.ceil(duration_s * rate_hz - 1e-9)
    if count + 1 > MAX_SAMPLES:
        raise ValueError(f'trajectory.duration_s = {duration_s} is too long ({count + 1} samples > {MAX_SAMPLES})')
    times = np.linspace(0.0, duration_s, count + 1)
    p, v, a = (np.zeros((times.size, 4)) for _ in range(3))
    for k, t in enumerate(times):
        where = f'{name}.update({t:.3f})'
        try:
            out = generator.update(float(t))
        except Exception as exc:  # noqa: BLE001  (user code)
            raise ValueError(f'{where} raised {type(exc).__name__}: {exc}') from None
        if not isinstance(out, dict):
            raise ValueError(f'{where} returned {type(out).__name__}, not a dict of flat outputs')
        p[k, :3], v[k, :3], a[k, :3] = (_vector(out, key, 3, where) for key in ('x', 'x_dot', 'x_ddot'))
        p[k, 3] = _vector(out, 'yaw', 1, where)[0]
        v[k, 3] = _vector(out, 'yaw_dot', 1, where, default=np.zeros(1))[0]
        a[k, 3] = _vector(out, 'yaw_ddot', 1, where, default=np.zeros(1))[0]
    p[:, 3] = np.unwrap(p[:, 3])
    return times, p, v, a


def to_polynomial(times, p, v, a) -> PiecewisePolynomial:
    """One quintic Hermite segment per sample interval."""
    h = np.diff(times)[:, None]
    coefficients = hermite_segment_coefficients(h, p[:-1], v[:-1], a[:-1], p[1:], v[1:], a[1:])
    return PiecewisePolynomial(h[:, 0], coefficients)


def _as_array(value):
    """A YAML list as the numpy array such classes compute with (rotorpy's circle multiplies its `freq` by 2 pi)."""
    return np.array(value, dtype=float) if isinstance(value, list) and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) for v in value) else value


def generate(waypoints, options, world=None) -> tuple[PiecewisePolynomial, np.ndarray]:
    """(the plan, its samples (K, 4)) of options.generator from the mission's waypoints (module docstring);
    quad_trajectory.planner.plan makes its PlanResult."""
    name = options.generator
    cls = resolve(name)
    try:
        args = {key: _as_array(value) for key, value in (options.generator_args or {}).items()}
        if options.generator_waypoints:
            generator = cls(np.array(waypoints, dtype=float), **args)
        else:
            generator = cls(**args)
    except Exception as exc:  # noqa: BLE001  (user code)
        raise ValueError(f'trajectory.generator {name!r}: building it failed: {type(exc).__name__}: {exc}') from None
    duration_s = options.duration_s if options.duration_s is not None else getattr(generator, 'duration_s', None)
    if not (isinstance(duration_s, (int, float)) and not isinstance(duration_s, bool) and math.isfinite(duration_s)
            and duration_s > 0):
        raise ValueError(f'trajectory.generator {name!r}: its duration is unknown ({duration_s!r}): set '
                         'trajectory.duration_s (seconds) or give the class a duration_s attribute')
    times, p, v, a = sample(generator, name, float(duration_s))
    trajectory = to_polynomial(times, p, v, a)
    if world is not None:
        segments, hit = collision.trajectory_collisions(world, trajectory, options.robot_radius_m)
        if segments.size:
            raise ValueError(f'trajectory.generator {name!r} collides with {world.name} at t = {hit[0]:.3f} s '
                             f'(robot_radius_m = {options.robot_radius_m})')
    return trajectory, p
