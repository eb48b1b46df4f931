"""Can this vehicle fly this plan? A check before flight (`quadflight plan` and `fly` run it).

From the plan's acceleration a, jerk j and snap s alone (differential flatness, Mellinger & Kumar 2011),
with e3 up and g = 9.81 m/s^2:
- collective specific thrust c = |a + g e3|, thrust direction z_b = (a + g e3) / c;
- tilt = acos(z_b . e3) <= max_tilt_deg (equivalently |a_xy| <= (a_z + g) tan(max_tilt));
- collective thrust m c within [thrust_min_n, thrust_max_n];
- tilt rate w = |dz_b/dt| = |j - (z_b . j) z_b| / c, angular acceleration
  alpha = |d2z_b/dt2 + w^2 z_b| = |s_perp / c - 2 (z_b . j) / c dz_b/dt| (s_perp: s without its z_b part);
- rotors: a roll/pitch moment I alpha in the worst direction is carried by two rotors at lever L (x and
  + frames alike), so the busiest rotor needs f = m c / 4 + I_xx alpha / (2 L), at rotor speed
  sqrt(f / k_eta) <= rotor_speed_max, and the idlest m c / 4 - I_xx alpha / (2 L) >= k_eta rotor_speed_min^2
  (a rotor cannot pull down: with rotor_speed_min 0 this is f >= 0);
- attitude loop: it follows a tilt ramp of rate w behind by lag_s w (lag_s = motor time constant + the
  loop's ramp lag, tilt_ramp_lag_s), so the tilt it must reach is tilt + lag_s w <= max_tilt_deg: the jerk
  it can follow, |j_perp| <= c (max_tilt - tilt) / lag_s.
Every check samples SAMPLES_PER_SEGMENT points per segment (ends included), in chunks of segments so a
100,000-segment plan is checked in bounded memory. No rclpy, no scipy.
"""

from dataclasses import dataclass, field

import numpy as np

from quad_common.types import GRAVITY_MPS2

SAMPLES_PER_SEGMENT = 32
_CHUNK = 4096
_E3 = np.array([0.0, 0.0, 1.0])


@dataclass
class Exceedance:
    """The worst sample of one check that the plan fails."""
    check: str          # tilt | thrust_max | thrust_min | rotor_speed_max | rotor_thrust_min | attitude_lag
    value: float        # what the plan needs there
    limit: float        # what the vehicle gives
    unit: str
    time_s: float       # from the plan's start
    segment: int
    samples_over: int   # samples of the whole plan over the limit

    @property
    def excess(self) -> float:
        """How far past the limit, as a fraction of it (0.25 = 25 % over); inf past a limit of 0."""
        return abs(self.value - self.limit) / abs(self.limit) if self.limit else float('inf')

    def __str__(self):
        by = f'{abs(self.value - self.limit):.4g} {self.unit}' + (
            f', {100 * self.excess:.0f} %' if self.limit else '')
        return (f'{self.check}: needs {self.value:.4g} {self.unit} at t = {self.time_s:.2f} s (segment '
                f'{self.segment}), the vehicle gives {self.limit:.4g} {self.unit}: over by {by} '
                f'({self.samples_over} samples)')


@dataclass
class Feasibility:
    vehicle: str
    peaks: dict = field(default_factory=dict)       # check -> largest value needed (smallest for *_min)
    limits: dict = field(default_factory=dict)      # check -> (limit, unit)
    exceeded: list = field(default_factory=list)    # Exceedance, worst first

    @property
    def ok(self) -> bool:
        return not self.exceeded

    def lines(self) -> list[str]:
        if self.ok:
            return [f'feasible on {self.vehicle}: ' + ', '.join(
                f'{k} {v:.4g} {self.limits[k][1]} ({">=" if k.endswith("_min") else "<="} {self.limits[k][0]:.4g})'
                for k, v in self.peaks.items())]
        return [f'NOT feasible on {self.vehicle}:'] + [f'  {e}' for e in self.exceeded]


@dataclass
class Preflight:
    """The check of the plan to be flown, and when it fails, the allocations that pass the same check."""
    feasibility: Feasibility
    time_allocation: str
    speed_mps: float
    planned_s: float
    alternatives: list = field(default_factory=list)   # (allocation, planned s, note) that pass, fastest first

    @property
    def ok(self) -> bool:
        return self.feasibility.ok

    @property
    def fits(self) -> str | None:
        """The first allocation that passes (fastest when it was planned), else None."""
        return self.alternatives[0][0] if self.alternatives else None

    def alternative(self, allocation: str):
        """(allocation, planned s, note) of `allocation` when it passes, else None."""
        return next((a for a in self.alternatives if a[0] == allocation), None)

    def lines(self) -> list[str]:
        out = self.feasibility.lines()
        if not self.ok:
            what = (f"the seed's sqrt profile at {self.speed_mps:g} m/s" if self.time_allocation == 'sqrt'
                    else f'time_allocation {self.time_allocation} at {self.speed_mps:g} m/s')
            out.append(f'{what} asks more than {self.feasibility.vehicle} gives ({self.planned_s:.2f} s planned)')
            for name, planned_s, note in self.alternatives:
                out.append(f'time_allocation {name} fits: {planned_s:.2f} s planned{note}: --time-allocation {name}, '
                           f'or trajectory.if_infeasible: {name} in the mission')
        return out


def tilt_ramp_lag_s(vehicle) -> float:
    """How far behind a tilt ramp the onboard loop runs: motor lag + the loop's own ramp lag.

    eq. 6 without roll/pitch rate feed-forward (the seed's p_des = q_des = 0): phi'' = kp e - kd phi' lags a
    ramp by kd / kp. An autopilot-like cascade with rate feed-forward lags by its rate loop, 1 / rate_p (by
    1 / angle_p without feed-forward); a shaped target ('lag' loop) by its time constant."""
    loop = getattr(vehicle, 'attitude_loop', None)
    kind = getattr(loop, 'type', 'eq6')
    if kind == 'lag':
        own = float(loop.time_constant_s)
    elif kind == 'so3_pd':
        own = 1.0 / float(loop.rate_p[0] if loop.use_feedforward_rates else loop.angle_p[0])
    else:
        kp, kd = float(vehicle.attitude_gains.kp[0]), float(vehicle.attitude_gains.kd[0])
        own = kd / kp if kp > 0 else float('inf')
    return float(vehicle.motor_time_constant_s) + own


def needs_from_derivatives(a, j, snap, vehicle) -> dict:
    """Per-sample needs from acceleration a, jerk j and snap (arrays (m, 3, S), a without gravity): tilt deg,
    thrust N, busiest rotor rad/s, idlest rotor thrust N, tilt + lag x tilt rate (deg); each (m, S)."""
    a = a + (GRAVITY_MPS2 * _E3)[None, :, None]
    c = np.maximum(np.sqrt(np.einsum('mas,mas->ms', a, a)), 1e-9)
    zb = a / c[:, None, :]
    zj = np.einsum('mas,mas->ms', zb, j)
    zdot = (j - zj[:, None, :] * zb) / c[:, None, :]
    rate = np.sqrt(np.einsum('mas,mas->ms', zdot, zdot))
    s_perp = snap - np.einsum('mas,mas->ms', zb, snap)[:, None, :] * zb
    alpha_vec = s_perp / c[:, None, :] - 2.0 * (zj / c)[:, None, :] * zdot
    alpha = np.sqrt(np.einsum('mas,mas->ms', alpha_vec, alpha_vec))
    tilt = np.degrees(np.arccos(np.clip(zb[:, 2, :], -1.0, 1.0)))
    thrust = vehicle.mass_kg * c
    moment_share = vehicle.inertia_kgm2[0] * alpha / (2.0 * vehicle.arm_length_m)
    busiest = np.sqrt(np.maximum(thrust / 4 + moment_share, 0.0) / vehicle.k_eta)
    idlest = thrust / 4 - moment_share
    lagged = tilt + np.degrees(tilt_ramp_lag_s(vehicle) * rate)
    return {'tilt': tilt, 'thrust_max': thrust, 'thrust_min': thrust, 'rotor_speed_max': busiest,
            'rotor_thrust_min': idlest, 'attitude_lag': lagged}


def derivatives(trajectory, segments, s):
    """Acceleration, jerk and snap (x, y, z) at normalised times s of `segments`: three arrays (m, 3, S)."""
    return tuple(trajectory.grid_values(order, s, segments, axes=3) for order in (2, 3, 4))


def margined_limits(vehicle, margin: float = 0.0) -> dict:
    """check -> (limit, unit, True where the need must stay below it), `margin` (a fraction) inside the
    vehicle's own limits: an upper limit times (1 - margin); a lower one raised by margin x its range (thrust:
    thrust_min + margin (thrust_max - thrust_min); a rotor's thrust likewise between its speed limits)."""
    if not 0.0 <= margin < 1.0:
        raise ValueError(f'margin = {margin!r} must be a fraction in [0, 1)')
    rotor_min = vehicle.k_eta * vehicle.rotor_speed_min_radps ** 2
    rotor_max = vehicle.k_eta * vehicle.rotor_speed_max_radps ** 2
    keep = 1.0 - margin
    return {
        'tilt': (keep * vehicle.max_tilt_deg, 'deg', True),
        'thrust_max': (keep * vehicle.thrust_max_n, 'N', True),
        'thrust_min': (vehicle.thrust_min_n + margin * (vehicle.thrust_max_n - vehicle.thrust_min_n), 'N', False),
        'rotor_speed_max': (keep * vehicle.rotor_speed_max_radps, 'rad/s', True),
        'rotor_thrust_min': (rotor_min + margin * (rotor_max - rotor_min), 'N', False),
        'attitude_lag': (keep * vehicle.max_tilt_deg, 'deg', True),
    }


def check(trajectory, vehicle, samples_per_segment: int = SAMPLES_PER_SEGMENT, margin: float = 0.0) -> Feasibility:
    """Check a PiecewisePolynomial plan against a quad_common Vehicle (its limits less `margin`, see limits());
    see the module docstring."""
    limits = margined_limits(vehicle, margin)
    s = np.linspace(0.0, 1.0, samples_per_segment)
    worst = {k: (-np.inf if upper else np.inf, 0, 0.0) for k, (_, _, upper) in limits.items()}  # value, seg, tau
    over = dict.fromkeys(limits, 0)
    for start in range(0, trajectory.n_segments, _CHUNK):
        part = slice(start, min(start + _CHUNK, trajectory.n_segments))
        for name, values in needs_from_derivatives(*derivatives(trajectory, part, s), vehicle).items():
            limit, _, upper = limits[name]
            flat = values.argmax() if upper else values.argmin()
            i, k = np.unravel_index(flat, values.shape)
            v = float(values[i, k])
            over[name] += int(np.count_nonzero(values > limit if upper else values < limit))
            if (v > worst[name][0]) if upper else (v < worst[name][0]):
                worst[name] = (v, start + int(i), float(s[k] * trajectory.durations_s[start + i]))
    report = Feasibility(vehicle=vehicle.name, peaks={k: w[0] for k, w in worst.items()},
                         limits={k: (lim, unit) for k, (lim, unit, _) in limits.items()})
    for name, (value, seg, tau) in worst.items():
        if over[name]:
            limit, unit, _ = limits[name]
            report.exceeded.append(Exceedance(name, value, limit, unit, float(trajectory.breaks_s[seg] + tau), seg,
                                              over[name]))
    report.exceeded.sort(key=lambda e: -e.excess)
    return report

