"""What a flight says about the vehicle that flew it (no rclpy): attitude response and thrust scale.

From any flight bag with `cmd/attitude_thrust` (the commanded attitude and specific force) and `odom` (the
measured state), simulated or flown on a real vehicle through the bridge:

- Attitude response, per roll and pitch axis: the measured angle y follows the commanded angle u as a first
  order plus dead time (FOPDT) model,
      tau y'(t) = K u(t - d) + c - y(t),
  fitted by output error (simulate the model, least squares on y - y_hat) for every dead time d on a grid and
  the best d kept. The lag the position loop sees is tau + d (the model's mean delay), the bandwidth
  1 / (2 pi tau) Hz; `attitude_lead_s` = that lag.
- Thrust scale k: the vertical acceleration the commanded specific force f really produces,
      a_z + g = k f R_33,
  so k = (1 + thrust error) / (1 + mass error) (the two are not separable from a flight: a 6 % weak thrust
  and a 6 % heavy vehicle fly the same). Fitted on velocity changes over 0.5 s windows (no differentiation
  of noisy odometry): dv_z + g dt = k integral(f R_33 dt). The hover thrust is g / k (m/s^2 of commanded
  specific force), the equivalent mass error 1 / k - 1.

Confidence: each estimate is repeated on BLOCKS contiguous parts of the flight (the lag's: of the span where its
command moves, see _parts); the 95 % interval is the whole-flight estimate +- t(0.975, n - 1) s / sqrt(n) over the
n parts that had enough excitation (errors in neighbouring samples are correlated, so the residuals of one fit would
understate it).

Fits that cannot be right are refused too (quality_refusal): tau at an edge of TAU_RANGE_S or the dead time at
MAX_DELAY_S (the true lag lies outside what was searched: e.g. the se3 controller's body rates fed forward on a PX4-like
cascade made it track within a sample, 0.005 s where the loop lags 0.154 s), a collapsed interval.

Window: only the time in which the vehicle flew our setpoints is scored (a bridge bag also holds the ground, the
pre-stream and the autopilot's own AUTO.LAND, where the controller commands what the vehicle never flies): the
bag's `vehicle/engaged` messages, else the bridge's hand-over diagnostics, cut the commands by their record
times; a simulator's bag (sim time, or /clock) is engaged throughout; a bag of a real vehicle that says neither
is refused. Fits whose R^2 or interval say the model does not hold are refused (quality_refusal).
"""

from dataclasses import asdict, dataclass

import numpy as np
import yaml
from scipy import optimize, signal, stats

from quad_common.types import GRAVITY_MPS2

DT_S = 0.01                  # resampling period (odometry comes at 100 Hz in the graph)
MAX_DELAY_S = 0.3
TAU_RANGE_S = (0.005, 2.0)   # the first order's search range (fit_fopdt's bounds)
BLOCKS = 6
MIN_PART_S = 2.0             # a part of the lag's interval lasts this long at least: in 1.5 s parts of an emulated
#   PX4 square one pitch part fitted tau at its 2 s bound (interval -1.2-1.6 s); 2 s parts fit 0.16-0.21 s there
MIN_LAG_PARTS = 3            # excited parts the lag's interval needs: over 2, t(0.975, 1) = 12.7 makes it useless
MIN_EXCITATION_RAD = np.deg2rad(0.5)   # command standard deviation a block needs to be fitted
MIN_BLOCK_EXCITATION_RAD = np.deg2rad(0.75)   # ... and each part of the interval: a part of hover before the
#   plan or of legs along the other axis fits noise (an emulated PX4 square at 1 m/s: a pitch part of 0.53 deg fit
#   0.28 s where the rest fit 0.17-0.19 s, widening the interval to 0.10-0.27 s and refusing a right 0.186 s)
WINDOW_S = 0.5               # thrust-scale windows
MIN_SPAN_S = 3.0
# Quality gates (quality_refusal). On the PX4 SIH bags: the OFFBOARD window fitted R^2 0.99, the landing phase
# 0.11-0.32 with a thrust scale of 0.55-0.78 (+-15 %); the plant family's flights fit R^2 > 0.95 and +-1 %.
MIN_FIT_R2 = 0.8
MAX_LAG_CI_REL = 0.5         # width of the lag's 95 % interval / the lag
MAX_THRUST_CI_REL = 0.05     # half width of the thrust scale's 95 % interval / the scale
EDGE_REL = 0.1               # tau within 10 % of a bound of TAU_RANGE_S, or the dead time at MAX_DELAY_S: at the edge
MIN_LAG_CI_S = 0.1 * DT_S    # a narrower lag interval: every part hit the same bound (collapsed), not a measurement
EXCITE_LAG = ('fly a manoeuvre that shows the attitude response: a 3 m square or a figure8 at 0.8-1 m/s with the pd '
              'controller (--controller pd: no body-rate feed-forward; the se3 controller\'s rates let an autopilot '
              'follow the commanded attitude within a sample and hide its lag), e.g. quadflight fly '
              'config/missions/figure8.yaml --controller pd')
EXCITE = ('fly a manoeuvre that tilts the vehicle while it flies our setpoints (offboard), e.g. a 3 m square or '
          'a figure8 at 0.8-1 m/s, and record all of it')
WALL_CLOCK_NS = 10**18       # stamps past 2001: a wall clock, not a simulator's time from 0


@dataclass
class AxisFit:
    axis: str
    tau_s: float
    delay_s: float
    gain: float
    lag_s: float              # tau + delay
    lag_ci95_s: tuple         # (low, high)
    bandwidth_hz: float       # 1 / (2 pi tau)
    fit_r2: float             # 1 - RSS / variance of y
    blocks: int               # parts fitted for the interval (those with MIN_BLOCK_EXCITATION_RAD of command)
    parts: int                # parts the span where the command moves was cut into (_parts)
    moving_s: float           # that span: first to last sample of the command off its median


@dataclass
class ThrustFit:
    thrust_scale: float
    thrust_scale_ci95: tuple
    hover_specific_force_mps2: float   # the commanded specific force that hovers: g / k
    mass_error_equivalent: float       # 1 / k - 1
    blocks: int


def _interval(estimate, parts):
    parts = np.asarray(parts, dtype=float)
    if len(parts) < 2:
        return (float('nan'), float('nan'))
    half = stats.t.ppf(0.975, len(parts) - 1) * parts.std(ddof=1) / np.sqrt(len(parts))
    return (float(estimate - half), float(estimate + half))


def _simulate(u_delayed, y0, tau_s, gain, bias):
    a = np.exp(-DT_S / tau_s)
    drive = (1 - a) * (gain * u_delayed + bias)
    out, _ = signal.lfilter([0.0, 1.0], [1.0, -a], drive, zi=[a * y0])
    out[0] = y0
    return out


def fit_fopdt(u, y):
    """(tau_s, delay_s, gain, bias, rss) of tau y' = K u(t - d) + c - y on uniformly sampled u, y (DT_S)."""
    fits = {}

    def fit(shift):
        if shift not in fits:
            ud = np.concatenate([np.full(shift, u[0]), u[:len(u) - shift]])

            def residual(p):
                return _simulate(ud, y[0], np.exp(p[0]), p[1], p[2]) - y

            r = optimize.least_squares(residual, [np.log(0.1), 1.0, 0.0], x_scale=[1.0, 0.1, 0.01],
                                       bounds=([np.log(TAU_RANGE_S[0]), 0.2, -0.5],
                                               [np.log(TAU_RANGE_S[1]), 5.0, 0.5]))
            fits[shift] = (float(np.exp(r.x[0])), shift * DT_S, float(r.x[1]), float(r.x[2]), float(r.fun @ r.fun))
        return fits[shift]

    coarse = 3   # dead times on a 3-sample grid, then every sample around the best
    last = int(round(MAX_DELAY_S / DT_S))
    best = min((fit(s) for s in range(0, last + 1, coarse)), key=lambda f: f[4])
    centre = int(round(best[1] / DT_S))
    return min((fit(s) for s in range(max(centre - coarse + 1, 0), min(centre + coarse, last + 1))),
               key=lambda f: f[4])


def _resample(t_cmd, cmd, t_odom, measured, t0, t1):
    grid = np.arange(t0, t1, DT_S)
    index = np.clip(np.searchsorted(t_cmd, grid, side='right') - 1, 0, len(t_cmd) - 1)  # zero-order hold
    return grid, cmd[index], np.interp(grid, t_odom, measured)


def _record_spans(events, close_at_last_true):
    """[(start, end)] bag-time spans in which events (time ns, bool) say true; close_at_last_true: end at the last
    true report (periodic reports: the end lies between it and the next false), else at the first false."""
    spans, start, last_true = [], None, None
    for t, on in events:
        if on:
            start = t if start is None else start
            last_true = t
        elif start is not None:
            spans.append((start, last_true if close_at_last_true else t))
            start = None
    if start is not None:
        spans.append((start, last_true if close_at_last_true else np.iinfo(np.int64).max))
    return spans


def engaged_window(flight) -> dict:
    """The longest span (header-stamp time) in which the vehicle flew our setpoints: {'t0', 't1', 'source'}.
    Commands belong to a span by their record time (the engaged messages and diagnostics carry no stamp of the
    commands' clock; a simulator's bag is stamped in sim time, recorded in wall time)."""
    if flight.engaged:
        spans, source = _record_spans(flight.engaged, close_at_last_true=False), 'vehicle/engaged'
    elif flight.handover:
        spans = _record_spans([(t, phase == 'active') for t, phase in flight.handover], close_at_last_true=True)
        source = 'the bridge\'s hand-over diagnostics'
    elif len(flight.clock_stamps_ns) or flight.odom_t[0] * 1e9 < WALL_CLOCK_NS:
        return {'t0': float(flight.cmd_t[0]), 't1': float(flight.cmd_t[-1]), 'source': 'simulator (engaged throughout)'}
    else:
        raise ValueError('the bag does not say when the vehicle flew our setpoints (no vehicle/engaged messages, '
                         'no mavlink_bridge hand-over diagnostics), so the ground, the pre-stream and the autopilot\'s '
                         'own landing would be scored: record vehicle/engaged and diagnostics with the flight '
                         '(quadflight record records both)')
    best = None
    for start, end in spans:
        inside = flight.cmd_t[(flight.cmd_record_ns >= start) & (flight.cmd_record_ns <= end)]
        if len(inside) > 1 and (best is None or inside[-1] - inside[0] > best[1] - best[0]):
            best = (float(inside.min()), float(inside.max()))
    if best is None:
        raise ValueError(f'the vehicle never flew our setpoints while cmd/attitude_thrust was recorded ({source}): '
                         f'nothing to identify; {EXCITE}')
    return {'t0': best[0], 't1': best[1], 'source': source}


def _span(flight):
    window = engaged_window(flight)
    t0 = max(flight.cmd_t[0], flight.odom_t[0], window['t0'])
    t1 = min(flight.cmd_t[-1], flight.odom_t[-1], window['t1'])
    if t1 - t0 < MIN_SPAN_S:
        raise ValueError(f'the bag has {max(t1 - t0, 0):.2f} s with both cmd/attitude_thrust and odom while the '
                         f'vehicle flew our setpoints ({window["source"]}); identification needs at least '
                         f'{MIN_SPAN_S} s: {EXCITE}')
    return t0, t1


def _airborne(flight, t0, t1):
    """The part of [t0, t1] after take-off: commanded specific force above half of g throughout."""
    low = flight.cmd_t[(flight.cmd_specific_force < 0.5 * GRAVITY_MPS2) & (flight.cmd_t >= t0) & (flight.cmd_t <= t1)]
    if len(low):
        late = low[low > t0 + 0.5 * (t1 - t0)]
        early = low[low <= t0 + 0.5 * (t1 - t0)]
        t0 = early[-1] if len(early) else t0
        t1 = late[0] if len(late) else t1
    return t0, t1


def _moving(u):
    """(first, end) sample indices of the span where the command moves: from the first to the last sample
    MIN_BLOCK_EXCITATION_RAD or more off its median (the hover attitude where the flight hovers long); (0, 0) where
    it never does."""
    away = np.flatnonzero(np.abs(u - np.median(u)) >= MIN_BLOCK_EXCITATION_RAD)
    return (int(away[0]), int(away[-1]) + 1) if len(away) else (0, 0)


def _parts(u, y):
    """The span where the command moves (_moving) in BLOCKS equal parts, or in as many as leave each MIN_PART_S:
    hover before or after the plan, however long the user waited, is in no part and changes neither their number nor
    their length (a part of hover with a little motion at its end fits a guess: 0.28 s where the rest fit 0.17-0.19
    s; parts cut from the whole window grow with the hover until too few of them move)."""
    first, end = _moving(u)
    count = min(BLOCKS, (end - first) // int(round(MIN_PART_S / DT_S)))
    edges = np.linspace(first, end, count + 1).round().astype(int)
    return [(u[a:b], y[a:b]) for a, b in zip(edges[:-1], edges[1:])]


def identify_attitude(flight, axis: int) -> AxisFit:
    """FOPDT fit of measured vs commanded roll (axis 0) or pitch (axis 1), with its 95 % interval."""
    name = ('roll', 'pitch')[axis]
    t0, t1 = _airborne(flight, *_span(flight))
    _, u, y = _resample(flight.cmd_t, flight.cmd_euler[:, axis], flight.odom_t, flight.euler[:, axis], t0, t1)
    if np.std(u) < MIN_EXCITATION_RAD:
        raise ValueError(f'the commanded {name} varies by {np.degrees(np.std(u)):.2f} deg (std); identification '
                         f'needs at least {np.degrees(MIN_EXCITATION_RAD):.1f} deg: fly a mission that moves')
    tau, delay, gain, _, rss = fit_fopdt(u, y)
    cut = _parts(u, y)
    lags = []
    for uu, yy in cut:
        if np.std(uu) >= MIN_BLOCK_EXCITATION_RAD:
            b_tau, b_delay, *_ = fit_fopdt(uu, yy)
            lags.append(b_tau + b_delay)
    lag = tau + delay
    first, end = _moving(u)
    return AxisFit(axis=name, tau_s=tau, delay_s=delay, gain=gain, lag_s=lag,
                   lag_ci95_s=_interval(lag, lags) if len(lags) >= MIN_LAG_PARTS else (float('nan'), float('nan')),
                   bandwidth_hz=1.0 / (2 * np.pi * tau), fit_r2=1.0 - rss / (len(y) * np.var(y)), blocks=len(lags),
                   parts=len(cut), moving_s=(end - first) * DT_S)


def identify_thrust(flight) -> ThrustFit:
    """Thrust scale k from a_z + g = k f R_33 over WINDOW_S windows, with its 95 % interval."""
    t0, t1 = _airborne(flight, *_span(flight))
    grid = np.arange(t0, t1, DT_S)
    index = np.clip(np.searchsorted(flight.cmd_t, grid, side='right') - 1, 0, len(flight.cmd_t) - 1)
    roll = np.interp(grid, flight.odom_t, flight.euler[:, 0])
    pitch = np.interp(grid, flight.odom_t, flight.euler[:, 1])
    drive = flight.cmd_specific_force[index] * np.cos(roll) * np.cos(pitch)   # f R_33 (Z-Y-X)
    vz = np.interp(grid, flight.odom_t, flight.velocity[:, 2])
    n = int(round(WINDOW_S / DT_S))
    starts = np.arange(0, len(grid) - n, n)
    lhs = np.array([vz[s + n] - vz[s] + GRAVITY_MPS2 * n * DT_S for s in starts])
    rhs = np.array([np.trapezoid(drive[s:s + n + 1], dx=DT_S) for s in starts])
    if len(starts) < 2:
        raise ValueError('too short a flight to estimate the thrust scale')
    k = float(lhs @ rhs / (rhs @ rhs))
    parts = [float(a @ b / (b @ b)) for a, b in zip(np.array_split(lhs, BLOCKS), np.array_split(rhs, BLOCKS))
             if len(b)]
    return ThrustFit(thrust_scale=k, thrust_scale_ci95=_interval(k, parts), hover_specific_force_mps2=GRAVITY_MPS2 / k,
                     mass_error_equivalent=1.0 / k - 1.0, blocks=len(parts))


def identify_drag(flight, thrust_scale: float, vehicle) -> dict:
    """Rotor drag c (quad_sim's and rotorpy's aerodynamics.rotor_drag_xy: body-frame horizontal force
    -c sum(omega) v_b) from the horizontal velocity changes over WINDOW_S windows,
        dv_xy = integral(k f (R e3)_xy dt) - c integral((sum(omega) / m) (R P R^T v)_xy dt),   P = diag(1, 1, 0),
    sum(omega) = 4 sqrt(k f m / (4 k_eta)) from the delivered thrust (no rotor speeds in the bag), m and k_eta the
    vehicle file's. {'rotor_drag_xy', 'rotor_drag_xy_ci95', 'deceleration_per_mps_at_hover'}."""
    from quad_common import rotations
    t0, t1 = _airborne(flight, *_span(flight))
    grid = np.arange(t0, t1, DT_S)
    index = np.clip(np.searchsorted(flight.cmd_t, grid, side='right') - 1, 0, len(flight.cmd_t) - 1)
    euler = np.stack([np.interp(grid, flight.odom_t, flight.euler[:, i]) for i in range(3)], axis=1)
    R = rotations.to_matrix(rotations.from_euler(euler[:, 0], euler[:, 1], euler[:, 2]))
    v = np.stack([np.interp(grid, flight.odom_t, flight.velocity[:, i]) for i in range(3)], axis=1)
    f = thrust_scale * flight.cmd_specific_force[index]
    drive = f[:, None] * R[:, :2, 2]                                       # k f (R e3)_xy
    v_body = np.einsum('nji,nj->ni', R, v)
    v_body[:, 2] = 0.0
    wsum = 4.0 * np.sqrt(np.maximum(f, 0.0) * vehicle.mass_kg / (4.0 * vehicle.k_eta))
    drag = (wsum / vehicle.mass_kg)[:, None] * np.einsum('nij,nj->ni', R, v_body)[:, :2]
    n = int(round(WINDOW_S / DT_S))
    starts = np.arange(0, len(grid) - n, n)
    if len(starts) < 2:
        raise ValueError('too short a flight to estimate drag')
    lhs = np.concatenate([v[s + n, :2] - v[s, :2] - np.trapezoid(drive[s:s + n + 1], dx=DT_S, axis=0)
                          for s in starts])
    rhs = -np.concatenate([np.trapezoid(drag[s:s + n + 1], dx=DT_S, axis=0) for s in starts])
    c = float(lhs @ rhs / (rhs @ rhs))
    parts = [float(a @ b / (b @ b)) for a, b in zip(np.array_split(lhs, BLOCKS), np.array_split(rhs, BLOCKS))
             if len(b) and b @ b > 0]
    hover_wsum = 4.0 * np.sqrt(vehicle.mass_kg * GRAVITY_MPS2 / (4.0 * vehicle.k_eta))
    return {'rotor_drag_xy': c, 'rotor_drag_xy_ci95': _interval(c, parts),
            'deceleration_per_mps_at_hover': c * hover_wsum / vehicle.mass_kg}


def identify(flight) -> dict:
    """{'roll': AxisFit, 'pitch': AxisFit, 'thrust': ThrustFit, 'attitude_lead_s': mean lag} as plain dicts."""
    if len(flight.cmd_t) == 0:
        raise ValueError('the bag has no commanded attitude (topic cmd/attitude_thrust): nothing to identify')
    roll, pitch = identify_attitude(flight, 0), identify_attitude(flight, 1)
    thrust = identify_thrust(flight)
    window = engaged_window(flight)
    t0, t1 = _airborne(flight, *_span(flight))
    return {'roll': asdict(roll), 'pitch': asdict(pitch), 'thrust': asdict(thrust),
            'attitude_lead_s': 0.5 * (roll.lag_s + pitch.lag_s), 'thrust_scale': thrust.thrust_scale,
            'window': {'source': window['source'], 'start_s': t0, 'end_s': t1, 'duration_s': t1 - t0}}


def quality_refusal(result: dict) -> str | None:
    """One line saying why the fits must not be used (a lag model that does not explain the measured angles, an
    interval too wide to trust, a thrust scale the controller cannot take), or None when they hold."""
    for axis in ('roll', 'pitch'):
        a = result[axis]
        if a['blocks'] < MIN_LAG_PARTS:   # no interval: too short or too gentle a flight (the 4 s maze at 2 m/s)
            if a['moving_s'] < MIN_LAG_PARTS * MIN_PART_S:
                return (f'the flight is too short to measure the {axis} lag: its {axis} command moves for '
                        f'{a["moving_s"]:.1f} s, the interval needs {MIN_LAG_PARTS} parts of {MIN_PART_S:g} s '
                        f'({MIN_LAG_PARTS * MIN_PART_S:g} s): {EXCITE_LAG}')
            return (f'the flight is too gentle to measure the {axis} lag: {a["blocks"]} of the {a["parts"]} parts of '
                    f'its {a["moving_s"]:.1f} s of {axis} motion command {np.rad2deg(MIN_BLOCK_EXCITATION_RAD):.2f} '
                    f'deg or more of {axis} (std), {MIN_LAG_PARTS} are needed: {EXCITE_LAG}')
        low, high = a['lag_ci95_s']
        if a['tau_s'] <= TAU_RANGE_S[0] * (1 + EDGE_REL) or a['tau_s'] >= TAU_RANGE_S[1] * (1 - EDGE_REL) \
                or a['delay_s'] >= MAX_DELAY_S - 0.5 * DT_S:
            return (f'the {axis} fit (lag {a["lag_s"]:.3f} s = tau {a["tau_s"]:.3f} s + dead time '
                    f'{a["delay_s"]:.3f} s) sits at the edge of its search range (tau {TAU_RANGE_S[0]}-'
                    f'{TAU_RANGE_S[1]} s, dead time up to {MAX_DELAY_S} s): the flight does not show the lag: '
                    f'{EXCITE_LAG}')
        if high - low < MIN_LAG_CI_S:
            return (f'the {axis} lag {a["lag_s"]:.3f} s has a collapsed 95 % interval {low:.4f}-{high:.4f} s over '
                    f'{a["blocks"]} parts (every part fitted the same bound): {EXCITE_LAG}')
        if not a['fit_r2'] >= MIN_FIT_R2:
            return (f'the {axis} fit explains R^2 {a["fit_r2"]:.2f} < {MIN_FIT_R2} of the measured {axis} (the vehicle '
                    f'did not fly these commands): {EXCITE}')
        if not high - low <= MAX_LAG_CI_REL * a['lag_s']:
            return (f'the {axis} lag {a["lag_s"]:.3f} s has a 95 % interval {low:.3f}-{high:.3f} s over '
                    f'{a["blocks"]} parts, wider than {MAX_LAG_CI_REL:.0%} of it: {EXCITE}')
    t = result['thrust']
    low, high = t['thrust_scale_ci95']
    k = t['thrust_scale']
    if not (0.5 <= k <= 2.0 and 0.5 * (high - low) <= MAX_THRUST_CI_REL * k):
        return (f'the thrust scale {k:.3f} (95 % {low:.3f}-{high:.3f}) is outside 0.5-2 or known no better than '
                f'+-{MAX_THRUST_CI_REL:.0%}: {EXCITE}')
    return None


def drag_measured(drag: dict) -> bool:
    """identify_drag's drag is taken where its 95 % interval lies above 0 (else the flight did not show one)."""
    return drag['rotor_drag_xy_ci95'][0] > 0


def profile(result: dict, base: dict | None = None) -> dict:
    """A position_controller params file: `base` (a control profile's content, without a top-level
    `identification` block that older versions wrote: rcl refuses any key beside a node's ros__parameters)
    with the identified attitude_lead_s and thrust_scale, and drag_feedforward_per_s = the drag measured
    (result['drag'], where its 95 % interval lies above 0; else 0: none measured)."""
    out = {k: v for k, v in (base or {}).items() if k != 'identification'}
    params = dict(out.get('position_controller', {}).get('ros__parameters', {}))
    params['attitude_lead_s'] = round(float(result['attitude_lead_s']), 4)
    params['thrust_scale'] = round(float(result['thrust_scale']), 4)
    drag = result.get('drag')
    if drag is not None:
        params['drag_feedforward_per_s'] = round(float(drag['deceleration_per_mps_at_hover']), 3) \
            if drag_measured(drag) else 0.0
    out['position_controller'] = {'ros__parameters': params}
    return out


# --soften: the base's horizontal proportional and integral gains times each factor in turn, until the margin check
# settles (kd kept: the loop slows and gains damping, so it stays stable behind a longer lag); half at most
SOFTEN_FACTORS = (0.9, 0.8, 0.7, 0.6, 0.5)
SOFTENED_GAINS = ('kp', 'ki')


def softened(written: dict, gains, factor: float) -> dict:
    """The profile `written` with kp and ki on x and y set to `factor` x their values in `gains` (the profile's
    effective PositionGains: a base that leaves one out flies the default, which is what is scaled)."""
    out = dict(written)
    params = dict(out['position_controller']['ros__parameters'])
    for name in SOFTENED_GAINS:
        for axis, value in zip('xy', getattr(gains, name)[:2]):
            params[f'{name}_{axis}'] = round(float(value) * factor, 4)
    out['position_controller'] = {'ros__parameters': params}
    return out


def vehicle_model(result: dict, vehicle_path) -> dict:
    """The vehicle file at vehicle_path as this flight measured it, for `fly --vehicle`, a sweep's `vehicles:` and
    the twin: attitude_loop `lag` with time_constant_s = the mean of roll and pitch tau + dead time (quad_sim's lag
    loop has one time constant and no dead time: the dead time enters as the mean delay it adds, so the lag the
    position loop sees is the one measured), thrust_error = k - 1 (plant only: delivered / commanded, the hover
    at g / k; a mass error flies the same), aerodynamics = the drag measured (result['drag'], identify_drag:
    rotor_drag_xy where its 95 % interval lies above 0, else 0; body and vertical drag 0: not separable at these
    speeds; the simulator applies them with a drag disturbance profile, as replay does), the rest (mass, inertia,
    motors: the bag records no rotor speeds) as the file says."""
    from quad_common.yaml_io import load_yaml
    data = {k: v for k, v in (load_yaml(vehicle_path) or {}).items() if k not in ('attitude_loop', 'thrust_error',
                                                                                  'mass_error')}
    lag_s = 0.5 * (result['roll']['tau_s'] + result['roll']['delay_s'] + result['pitch']['tau_s']
                   + result['pitch']['delay_s'])
    data['name'] = f'{data.get("name", "vehicle")}_identified'
    data['attitude_loop'] = {'type': 'lag', 'time_constant_s': round(float(lag_s), 4)}
    data['thrust_error'] = round(float(result['thrust_scale']) - 1.0, 4)
    drag = result.get('drag')
    if drag is not None:
        measured = drag_measured(drag)
        data['aerodynamics'] = {'body_drag': [0.0, 0.0, 0.0],
                                'rotor_drag_xy': float(f'{drag["rotor_drag_xy"]:.4g}') if measured else 0.0,
                                'rotor_drag_z': 0.0}
    return data


def model_text(model: dict, result: dict, title: str) -> str:
    """The vehicle model file: `title`, what was measured per axis (tau, dead time) and the hover thrust as
    comments, then the vehicle fields."""
    lines = [f'# {title}']
    for axis in ('roll', 'pitch'):
        a = result[axis]
        lines.append(f'# {axis}: tau {a["tau_s"]:.4f} s + dead time {a["delay_s"]:.3f} s = lag {a["lag_s"]:.4f} s '
                     f'(95 % {a["lag_ci95_s"][0]:.4f}-{a["lag_ci95_s"][1]:.4f}), R^2 {a["fit_r2"]:.3f}')
    t = result['thrust']
    lines.append(f'# thrust scale {t["thrust_scale"]:.4f}: hover at {t["hover_specific_force_mps2"]:.3f} m/s^2 '
                 f'commanded; motor time constant not measured (no rotor speeds in the bag)')
    drag = result.get('drag')
    if drag is not None:
        low, high = drag['rotor_drag_xy_ci95']
        lines.append(f'# rotor drag {drag["rotor_drag_xy"]:.4g} N/(m/s)/(rad/s) (95 % {low:.4g}-{high:.4g}): '
                     f'{drag["deceleration_per_mps_at_hover"]:.3f} m/s^2 per m/s at hover')
    return '\n'.join(lines) + '\n' + yaml.safe_dump(model, sort_keys=False)


IDENTIFICATION_HEADER = '# identification:'


def profile_text(written: dict, facts: dict, title: str) -> str:
    """The profile file: `title` and the identification facts as YAML comments (rcl and the launch files read
    only the parameters; read_identification reads the facts back), then the parameters."""
    facts_yaml = yaml.safe_dump({'identification': _plain(facts)}, sort_keys=False).splitlines()[1:]
    comments = [f'# {title}', IDENTIFICATION_HEADER, *(f'#{line}' for line in facts_yaml)]
    return '\n'.join(comments) + '\n' + yaml.safe_dump(written, sort_keys=False)


def read_identification(text: str) -> dict:
    """The facts profile_text wrote into a profile's comments."""
    lines = text.splitlines()
    start = lines.index(IDENTIFICATION_HEADER)
    block = []
    for line in lines[start + 1:]:
        if not line.startswith('#  '):
            break
        block.append(line[1:])
    return yaml.safe_load('identification:\n' + '\n'.join(block))['identification']


def _plain(value):
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return float(f'{float(value):.5g}') if abs(value) < 1e-3 else round(float(value), 5)   # drag: ~1e-6
    return value
