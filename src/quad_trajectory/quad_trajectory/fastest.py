"""The `fastest` time allocation: the shortest total time whose plan the vehicle can fly with a margin.

Problem: over the segment times T (points, method and waypoint constraint fixed), minimise sum_i T_i subject
to every sample of every segment meeting feasibility.py's checks (tilt, collective thrust, rotor speed and
thrust, tilt + attitude lag x tilt rate) against the vehicle's limits less `margin` (feasibility.margined_limits:
an upper limit times 1 - margin, a lower one raised by margin x its range). The result is scaled to pass them
at feasibility.py's own 32 samples a segment, the check `quadflight plan` and `fly` run before flight.

Method: a trust-region sequential linear programme in x = log T, every iterate made exactly feasible by
uniform scaling.
- Uniform scaling is exact (planner._limit_times): times k T give p(t / k), so acceleration, jerk and snap at
  a segment's samples divide by k^2, k^3, k^4 without a new solve. `feasible_scale` finds the smallest k with
  every sample inside the limits: each need falls monotonically towards its hover value as k grows, so a
  bracket is found from k = 1 outwards and the root (Illinois regula falsi in log k) only over the samples that
  fail at the bracket's low end.
- Start: the sqrt shape, then EQUALISE_ROUNDS rounds of T_i <- T_i k_i with k_i the scale that makes segment i
  alone just feasible (its neighbours' coupling ignored; a vectorised bisection for all segments at once); the
  shortest of these, scaled, starts the search.
- Step: the normalised violation of each check at each sample, v (need / limit - 1 above, (limit - need) /
  range below; <= 0 feasible), and its Jacobian dv/dx. The spline's normalised-time coefficients y solve
  A(T) y = b (solver.System; b is the points), and only the continuity rows' factors (T_k+1 / T_k)^p depend on
  T, so dy/dx_j = -A^-1 (dA/dx_j y): one banded LU of A (LAPACK gbtrf) gives y and every direction's dy by
  back-substitution. Derivative q at the normalised time s is T^-q P^(q)(s), so its change is
  T^-q dP^(q)(s) - q dx p^(q); the needs (a pointwise function of a, j, snap) change along it by a
  directional difference of step NEEDS_STEP, without a new solve. A change of T_j moves the spline mostly near
  segment j (a joint's influence decays geometrically along a minimum-derivative spline), so dv/dx is taken
  banded: BAND segments either side, every (2 BAND + 1)-th segment moved at once in one direction (2 BAND + 1
  directions). The linear programme min sum_j T_j d_j s.t. v_r + J_r d <= 0 for every (check, sample)
  within NEAR x the trust radius of its limit (less the rows no step inside the box reaches,
  v_r + trust |J_r|_1 <= 0), |d_j| <= trust radius (HiGHS), gives the step; the new shape is scaled to the
  limits again and kept when its total time is shorter; the trust radius follows how well the programme
  predicted the gain.
  A plan longer than LP_BLOCK + 2 LP_OVERLAP segments solves the programme in overlapping windows (_lp_step).
  BAND = 5 matters: with 3, the directions alias the influence of segments 4 away (about 20 % error in the
  Jacobian) and the search stalls 2-3 % short of the optimum on slalom_dense.
  Every near sample is a row, not only each segment's peak: the peak moves between samples as the times
  change, and a programme that sees only the peaks steps into the samples it does not see.
- Stop: after MAX_ITERATIONS steps, when the radius falls below MIN_TRUST, or when the programme predicts
  less than STALL_GAIN of the total time.
The search samples LOOP_SAMPLES points a segment (fewer rows in each programme), the result is then scaled to
pass at feasibility.py's 32. Cost per step: one banded LU with 2 BAND + 2 right-hand sides, 2 BAND + 2 need
evaluations, one solve and scale for the new shape, one LP. Measured against a brute-force
reference (scipy SLSQP over all times, every sample a constraint, several starts) in bench/bench_fastest.py.

Short first and last legs: a leg from rest to cruise asks for a spike of acceleration when it is given the
same time as its neighbours (the sqrt profile on long_100: 3.9 m/s^2 against 0.2 mid-flight). Here that spike
is a sample like any other, so the first and last legs are lengthened until it fits the same limits as the rest.
"""

import numpy as np

from quad_trajectory import feasibility, solver, timing
from quad_trajectory.polynomial import PiecewisePolynomial, derivative_factors

BAND = 5                 # segments either side in the banded Jacobian
LP_BLOCK, LP_OVERLAP = 150, 25   # a long plan's step: blocks of 150 segments, each with 25 either side
MAX_ITERATIONS = 20
MIN_TRUST = 2e-3         # log-time trust radius below which the search stops
FIRST_TRUST = 0.3
GROW, SHRINK = 2.0, 0.4
GROW_RATIO = 0.75        # a full step whose gain was at least this fraction of the predicted one grows the radius
STALL_GAIN = 2e-4        # a step predicted to gain less than this fraction of the time ends the search
LOOP_SAMPLES = 10        # samples a segment inside the search (the result is scaled to feasibility.py's 32)
SEGMENT_BISECTIONS = 14  # of each segment's own scale in the start (log k to 4e-4)
EQUALISE_ROUNDS = 3      # start: each segment scaled to its own limit, this many times
NEAR = 1.0               # (check, sample) pairs within NEAR x the trust radius of their limit enter the step
NEEDS_STEP = 1e-7        # step of the needs' directional derivative along a colour's change of a, j, snap
_ROOT_ITERATIONS = 60     # of the scale's root finding (Illinois), to _ROOT_TOLERANCE in log k
_ROOT_TOLERANCE = 1e-7
_SAFETY = 1.0 + 1e-7     # the returned scale a hair above the root finder's feasible end
DEFAULT_MARGIN = 0.1


class Constraints:
    """The margined limits of one vehicle as normalised per-sample violations (<= 0 feasible)."""

    def __init__(self, vehicle, margin=DEFAULT_MARGIN, samples_per_segment=feasibility.SAMPLES_PER_SEGMENT):
        self.vehicle = vehicle
        self.limits = feasibility.margined_limits(vehicle, margin)
        rotor_range = vehicle.k_eta * (vehicle.rotor_speed_max_radps ** 2 - vehicle.rotor_speed_min_radps ** 2)
        self._range = {'thrust_min': vehicle.thrust_max_n - vehicle.thrust_min_n, 'rotor_thrust_min': rotor_range}
        self.s = np.linspace(0.0, 1.0, samples_per_segment)
        self.margin = margin

    def check_hover(self):
        """ValueError naming the check when hover itself is outside the margined limits (then no slow-down fits)."""
        zero = np.zeros((1, 3, 1))
        needs = feasibility.needs_from_derivatives(zero, zero, zero, self.vehicle)
        for name, (limit, unit, upper) in self.limits.items():
            need = float(needs[name][0, 0])
            if need > limit if upper else need < limit:
                raise ValueError(f'margin = {self.margin:g} leaves {self.vehicle.name} no hover: {name} needs '
                                 f'{need:.4g} {unit} at hover, the limit less the margin is {limit:.4g} {unit}')

    def violations(self, a, j, snap) -> np.ndarray:
        """The normalised violation of each check at each sample: (checks, m, S)."""
        needs = feasibility.needs_from_derivatives(a, j, snap, self.vehicle)
        return np.stack([needs[name] / limit - 1.0 if upper else (limit - needs[name]) / self._range[name]
                         for name, (limit, _, upper) in self.limits.items()])

    def violation(self, a, j, snap) -> np.ndarray:
        """The worst check's normalised violation at each sample: (m, S)."""
        return self.violations(a, j, snap).max(axis=0)

    def derivatives(self, trajectory):
        return feasibility.derivatives(trajectory, slice(None), self.s)

    def sample_violations(self, trajectory) -> np.ndarray:
        return self.violations(*self.derivatives(trajectory))

    def feasible_scale(self, trajectory) -> float:
        """The smallest k such that the plan with times k T meets every limit at every sample.

        Each need falls monotonically towards its hover value as k grows, so a sample feasible at some k is
        feasible above it: a bracket [lo, hi] (hi feasible) is found from k = 1 outwards, and the root is
        found over only the samples that fail at lo."""
        a, j, snap = self.derivatives(trajectory)

        def worst(k, a, j, snap):
            return self.violation(a / k ** 2, j / k ** 3, snap / k ** 4).max(axis=1)

        w = worst(1.0, a, j, snap)
        if w.max() > 0.0:
            lo, bad = 1.0, w > 0.0
            a, j, snap = a[bad], j[bad], snap[bad]
            hi = 1.0
            while True:
                hi *= 1.0 + max(w.max(), 0.05)
                if worst(hi, a, j, snap).max() <= 0.0:
                    break
                if hi > 1e6:
                    raise ValueError('no uniform slow-down of this plan fits the vehicle')
        else:
            hi, lo = 1.0, 1.0
            factor = max(1.0 + w.max(), 0.25) ** 0.5 * 0.99   # the needs grow at least ~ 1 / k^2 below hover
            while True:
                lo *= factor
                w = worst(lo, a, j, snap)
                if w.max() > 0.0:
                    break
                hi, factor = lo, 0.8
                if lo < 1e-6:
                    return lo
            bad = w > 0.0
            a, j, snap = a[bad], j[bad], snap[bad]

        def f(log_k):
            return float(worst(np.exp(log_k), a, j, snap).max())

        # Illinois regula falsi on the worst violation over log k: bracketing, so it converges like bisection
        # at worst, and in a handful of evaluations on this smooth, monotone function
        x0, x1 = np.log(lo), np.log(hi)
        f0, f1 = f(x0), f(x1)
        side = 0
        for _ in range(_ROOT_ITERATIONS):
            if x1 - x0 < _ROOT_TOLERANCE:
                break
            x = x1 - f1 * (x1 - x0) / (f1 - f0) if f1 != f0 else 0.5 * (x0 + x1)
            x = min(max(x, x0 + 0.01 * (x1 - x0)), x1 - 0.01 * (x1 - x0))
            fx = f(x)
            if fx <= 0.0:
                x1, f1 = x, fx
                if side == 1:
                    f0 *= 0.5
                side = 1
            else:
                x0, f0 = x, fx
                if side == -1:
                    f1 *= 0.5
                side = -1
        return float(np.exp(x1)) * _SAFETY

    def segment_scales(self, trajectory, iterations=SEGMENT_BISECTIONS) -> np.ndarray:
        """Per segment, the k that would make that segment's own samples just feasible with times k T (its
        neighbours' coupling ignored): bisection in log k, all segments at once. (M,)"""
        a, j, snap = self.derivatives(trajectory)
        lo, hi = np.full(a.shape[0], -3.0), np.full(a.shape[0], 3.0)
        for _ in range(iterations):
            mid = 0.5 * (lo + hi)
            k = np.exp(mid)[:, None, None]
            ok = self.violation(a / k ** 2, j / k ** 3, snap / k ** 4).max(axis=1) <= 0.0
            hi, lo = np.where(ok, mid, hi), np.where(ok, lo, mid)
        return np.exp(hi)


def _linearised_constraints(system, points, x, constraints, near):
    """Rows v_r + J_r d <= 0 of every (check, sample) within `near` of its limit (v > -near), with J = dv/dx
    from one banded LU of the spline's system (_coefficient_directions) and the needs' directional derivative
    along each colour's exact change of acceleration, jerk and snap; returns (J sparse, v_r). Every near sample
    is a row, not only each segment's peak: the peak moves between samples as the times change, and a programme
    that sees only the peaks steps into the samples it does not see."""
    from scipy.sparse import csr_matrix

    m = x.size
    T = np.exp(x)
    width = min(2 * BAND + 1, m)
    directions = np.zeros((width, m))
    for color in range(width):
        directions[color, color::2 * BAND + 1] = 1.0
    (a, j, snap), moved_by = _derivative_directions(system, points, T, directions, constraints.s)
    v = constraints.violations(a, j, snap)
    active = v > -near
    segment = np.nonzero(active)[1]          # the segment of each row
    row = np.arange(segment.size)
    rows, cols, vals = [], [], []
    for color in range(width):
        da, dj, ds = moved_by[color]
        dv = (constraints.violations(a + NEEDS_STEP * da, j + NEEDS_STEP * dj, snap + NEEDS_STEP * ds)[active]
              - v[active]) / NEEDS_STEP
        # the perturbed segment within BAND of each row's segment: the one congruent to color modulo 2 BAND + 1
        moved = segment + (color - segment + BAND) % (2 * BAND + 1) - BAND
        keep = (moved >= 0) & (moved < m)
        rows.append(row[keep])
        cols.append(moved[keep])
        vals.append(dv[keep])
    J = csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(segment.size, m))
    return J, v[active]


def _derivative_directions(system, points, T, directions, s):
    """Acceleration, jerk and snap (m, 3, S) of the spline with times T, and their derivatives along each row
    of `directions` (D, m) in x = log T: D triples (m, 3, S).

    The normalised-time coefficients y solve A(T) y = b (solver.System; b does not depend on T; the only
    T-dependent entries are the continuity rows' (T_k+1 / T_k)^p, with d/dx of them p (T_k+1 / T_k)^p
    (dx_k+1 - dx_k)), so dy = -A^-1 (dA y): one banded LU (LAPACK gbtrf) for y and every direction (gbtrs).
    In normalised time p^(q)(T s) = T^-q P^(q)(s), so d p^(q) = T^-q dP^(q) - q dx p^(q)."""
    from scipy.linalg.lapack import dgbtrf, dgbtrs
    from scipy.sparse import csr_matrix

    rows, cols, vals = system.triplets(T)
    n_rows, lower, upper = 2 * system.r * system.m, system.lower, system.upper
    ab = np.zeros((2 * lower + upper + 1, n_rows))
    ab[lower + system._band_rows, cols] = vals
    lu, pivots, info = dgbtrf(ab, lower, upper)
    if info != 0:
        raise ValueError(f'the spline system is singular at these times (LAPACK gbtrf info {info})')
    b = system.rhs(np.asarray(points, dtype=float)[:, :3])
    y, _ = dgbtrs(lu, lower, upper, b, pivots)
    k = system.joint[system.scaled]
    slope = vals[system.scaled] * system.power[system.scaled]          # d val / d(x_k+1 - x_k)
    dA = slope[None, :] * (directions[:, k + 1] - directions[:, k])    # (D, scaled)
    r_rows, r_cols = rows[system.scaled], cols[system.scaled]
    n_dir = directions.shape[0]
    gather = csr_matrix((np.ones(r_rows.size), (r_rows, np.arange(r_rows.size))), shape=(n_rows, r_rows.size))
    rhs = gather @ (-dA.T[:, :, None] * y[r_cols][:, None, :]).reshape(r_rows.size, n_dir * 3)
    dy, _ = dgbtrs(lu, lower, upper, rhs, pivots)
    n = 2 * system.r
    s = np.asarray(s, dtype=float)
    y = y.reshape(system.m, n, 3)
    dy = dy.reshape(system.m, n, n_dir, 3)
    values, moved = [], [[] for _ in range(n_dir)]
    for q in (2, 3, 4):
        if q >= n:
            basis = np.zeros((n, s.size))
        else:
            basis = np.zeros((n, s.size))
            basis[q:] = derivative_factors(n, q)[:, None] * s[None, :] ** np.arange(n - q)[:, None]
        scale = T[:, None, None] ** -q
        value = np.einsum('mka,ks->mas', y, basis) * scale
        change = np.einsum('mkda,ks->dmas', dy, basis) * scale[None]
        values.append(value)
        for d in range(n_dir):
            moved[d].append(change[d] - q * directions[d][:, None, None] * value)
    return tuple(values), moved


def _row_spans(J):
    """Each row's first and last column of a CSR matrix (m and -1 for a row without entries, which then fits
    every window). reduceat's last row runs to the end of the array, so each ends in a sentinel that neither
    reduction picks."""
    m = J.shape[1]
    empty = np.diff(J.indptr) == 0
    starts = J.indptr[:-1]
    first = np.where(empty, m, np.minimum.reduceat(np.append(J.indices, m), starts))
    last = np.where(empty, -1, np.maximum.reduceat(np.append(J.indices, -1), starts))
    return first, last


def _lp_step(T, J, g, trust):
    """The step d: min sum_j T_j d_j s.t. g + J d <= 0, |d_j| <= trust (HiGHS), or None if it fails.

    J is banded, so a long plan is cut into blocks of LP_BLOCK segments, each solved with LP_OVERLAP segments
    either side (rows entirely inside that window, the rest of d held at 0) and keeping its own block's part:
    the cost stays linear in the segments where one programme over all of them grows faster. d = 0 is feasible
    in every window (the current plan is), so each has a solution; the joined step is then judged like any other.
    """
    from scipy.optimize import linprog

    m = T.size
    if m <= LP_BLOCK + 2 * LP_OVERLAP:
        res = linprog(T, A_ub=J, b_ub=-g, bounds=(-trust, trust), method='highs', options={'presolve': False})
        return res.x if res.status == 0 else None
    first, last = _row_spans(J)
    d = np.zeros(m)
    for start in range(0, m, LP_BLOCK):
        stop = min(start + LP_BLOCK, m)
        lo, hi = max(0, start - LP_OVERLAP), min(m, stop + LP_OVERLAP)
        inside = np.nonzero((first >= lo) & (last < hi))[0]
        res = linprog(T[lo:hi], A_ub=J[inside][:, lo:hi], b_ub=-g[inside], bounds=(-trust, trust), method='highs',
                      options={'presolve': False})
        if res.status != 0:
            return None
        d[start:stop] = res.x[start - lo:stop - lo]
    return d


def fastest_times(points, vehicle, method='minsnap', mode='continuity', margin=DEFAULT_MARGIN, start_shapes=None,
                  log=None):
    """Segment times (M,) of the shortest plan found whose every sample meets the vehicle's limits less
    `margin`, for these points, method and waypoint constraint. See the module docstring."""
    points = np.asarray(points, dtype=float)
    system = solver.System(len(points) - 1, solver.ORDERS[method], mode)

    def solve(T):
        return PiecewisePolynomial(T, system.solve(T, points, banded=True))

    constraints = Constraints(vehicle, margin, LOOP_SAMPLES)
    constraints.check_hover()
    shapes = start_shapes if start_shapes is not None else (timing.sqrt_allocation(points, 1.0),)
    best = None
    for shape in shapes:
        T = np.asarray(shape, dtype=float)
        for _ in range(EQUALISE_ROUNDS + 1):
            trajectory = solve(T)
            candidate = T * constraints.feasible_scale(trajectory)
            if best is None or candidate.sum() < best.sum():
                best = candidate
            T = T * constraints.segment_scales(trajectory)
    T = best
    trust = FIRST_TRUST
    J = None
    for iteration in range(MAX_ITERATIONS):
        if trust < MIN_TRUST:
            break
        near = min(NEAR * trust, 1.0)
        if J is None:   # kept while steps from the same point are refused
            J, g = _linearised_constraints(system, points, np.log(T), constraints, near)
        # a row that no step inside the box can reach (g_r + trust |J_r|_1 <= 0) cannot bind: left out
        rows = g + trust * np.asarray(abs(J).sum(axis=1)).ravel() > 0.0
        d = _lp_step(T, J[rows], g[rows], trust)
        if d is None:
            trust *= SHRINK
            continue
        predicted = -float(T @ d)        # the time the linearised step saves
        if predicted < STALL_GAIN * T.sum():
            break
        shape = T * np.exp(d)
        candidate = shape * constraints.feasible_scale(solve(shape))
        actual = T.sum() - candidate.sum()
        if log is not None:
            log(f'fastest: step {iteration}: trust {trust:.3g}, {T.sum():.4f} s -> {candidate.sum():.4f} s '
                f'(predicted {T.sum() - predicted:.4f} s)')
        ratio = actual / predicted
        if ratio > 0.0:
            T, J = candidate, None
        # the usual trust-region update on how well the linear model predicted the gain
        step = float(np.abs(d).max())
        if ratio < 0.25:
            trust = SHRINK * step
        elif ratio > GROW_RATIO and step > 0.99 * trust:
            trust = min(GROW * trust, 1.0)
    # the search samples LOOP_SAMPLES points a segment; the plan is checked (and flown) at feasibility.py's
    return T * Constraints(vehicle, margin).feasible_scale(solve(T))
