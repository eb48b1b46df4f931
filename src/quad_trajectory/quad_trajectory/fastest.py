"""The `fastest` time allocation: the shortest total time whose plan the vehicle can fly with a margin.

Problem: over the segment times T (points, method and waypoint constraint fixed), minimise sum_i T_i subject
to every sample of every segment meeting feasibility.py's checks (tilt, collective thrust, rotor speed and
thrust, tilt + attitude lag x tilt rate) against the vehicle's limits less `margin` (feasibility.margined_limits:
an upper limit times 1 - margin, a lower one raised by margin x its range). The result is scaled to pass them
at feasibility.py's own 32 samples a segment, the check `quadflight plan` and `fly` run before flight.

Method: a trust-region sequential linear programme in x = log T, judged by uniform scaling.
- Uniform scaling is exact (planner._limit_times): times k T give p(t / k), so acceleration, jerk and snap at a
  segment's samples divide by k^2, k^3, k^4 without a new solve. `feasible_scale` finds the smallest k with every
  sample inside the limits: each need falls monotonically towards its hover value as k grows, so a bracket is found
  from k = 1 outwards and the root (Illinois regula falsi in log k) only over the samples that fail at the bracket's
  low end, until the bracket or the secant's distance from its feasible end to the root is below tolerance (the
  feasible end is returned, so the scale errs only on the slow side). The tilt check is left out: tilt + lag x tilt
  rate >= tilt under the same limit, so attitude_lag passing implies it.
- Start: the sqrt shape, then EQUALISE_ROUNDS rounds of T_i <- T_i k_i with k_i the scale that makes segment i
  alone just feasible (its neighbours' coupling ignored; a vectorised bisection for all segments at once); the
  shortest of these, scaled, starts the search.
- Step: the normalised violation of each check at each sample, v (need / limit - 1 above, (limit - need) / range
  below; <= 0 feasible), and its Jacobian dv/dx. The spline's normalised-time coefficients y solve A(T) y = b
  (solver.System; b is the points), and only the continuity rows' factors (T_k+1 / T_k)^p depend on T, so dy/dx_j =
  -A^-1 (dA/dx_j y): one banded LU of A (LAPACK gbtrf) gives y and every direction's dy by back-substitution.
  Derivative q at the normalised time s is T^-q P^(q)(s), so its change is T^-q dP^(q)(s) - q dx p^(q); the needs (a
  pointwise function of a, j, snap) change along it by a directional difference of step NEEDS_STEP, without a new
  solve. A change of T_j moves the spline mostly near segment j (a joint's influence decays geometrically along a
  minimum-derivative spline), so dv/dx is taken banded: BAND segments either side, every (2 BAND + 1)-th segment
  moved at once in one direction (2 BAND + 1 directions), each row of J held as its 2 BAND + 1 entries (BandRows).
  The linear programme min sum_j T_j d_j s.t. v_r + J_r d <= 0 for every (check, sample) within NEAR x the trust
  radius of its limit (less the rows no step inside the box reaches, v_r + trust |J_r|_1 <= 0), |d_j| <= trust
  radius, gives the step (_lp_step: an interior-point method whose Newton systems J^T W J are banded, factorised by
  LAPACK's dpbtrf directly, so a step costs O(rows) at any length of plan; scipy's HiGHS took 2.8x as long on the
  same programmes at 100 segments and 3.9x at 1000). The new shape, scaled to the limits, is compared with the best
  so far; when shorter, it is kept scaled as the best and unscaled as the next iterate: its samples just outside the
  limits enter the next programme with v_r > 0 and are pulled back by its step, where scaling the whole plan for one
  overshoot would throw most of the step away (on 100 segments 35.5 s against 36.3 s when every iterate was scaled).
  An iterate that no step within the radius pulls back (the programme has no solution) gives way to the best. The
  trust radius follows how well the programme predicted the gain.
  BAND = 5 matters: with 3, the directions alias the influence of segments 4 away (about 20 % error in the
  Jacobian) and the search stalls 2-3 % short of the optimum on slalom_dense.
  Every near sample is a row, not only each segment's peak: the peak moves between samples as the times
  change, and a programme that sees only the peaks (or only each local peak and its neighbours) steps into
  the samples it does not see.
- Stop: after MAX_ITERATIONS steps, when the radius falls below MIN_TRUST, when the programme predicts
  less than STALL_GAIN of the total time, or when a kept step gained less than SETTLED_GAIN of it: gains that
  small are below what rescaling from the search's LOOP_SAMPLES to feasibility.py's 32 moves the total
  (about 0.4 % on the 100-segment survey), so further steps rarely shorten the returned plan.
The search samples LOOP_SAMPLES points a segment (fewer rows in each programme), the result is then scaled to
pass at feasibility.py's 32. Cost per step: one banded LU with 2 BAND + 2 right-hand sides, one need
evaluation over the 2 BAND + 1 directions at once, one solve and scale for the new shape, one programme of
about a dozen banded Cholesky factorisations. Measured against a brute-force reference (scipy SLSQP over all
times, every sample a constraint, several starts) in bench/bench_fastest.py.

Short first and last legs: a leg from rest to cruise asks for a spike of acceleration when it is given the
same time as its neighbours (the sqrt profile on long_100: 3.9 m/s^2 against 0.2 mid-flight). Here that spike
is a sample like any other, so the first and last legs are lengthened until it fits the same limits as the rest.
"""

import numpy as np

from quad_trajectory import feasibility, solver, timing
from quad_trajectory.plan_inputs import DEFAULT_MARGIN
from quad_trajectory.polynomial import PiecewisePolynomial, derivative_factors

BAND = 5                 # segments either side in the banded Jacobian
LP_ITERATIONS = 60       # of the step's interior-point method
LP_TOLERANCE = 1e-6      # its residuals and duality gap, relative to the problem's scale
DIVERGED = 1e8           # a gap this many times its start: the programme has no solution
MAX_ITERATIONS = 20
MIN_TRUST = 2e-3         # log-time trust radius below which the search stops
FIRST_TRUST = 0.3
GROW, SHRINK = 2.0, 0.4
GROW_RATIO = 0.75        # a full step whose gain was at least this fraction of the predicted one grows the radius
STALL_GAIN = 1e-3        # a step predicted to gain less than this fraction of the time ends the search
SETTLED_GAIN = 5e-4      # a kept step that gained less than this fraction of the time ends the search
LOOP_SAMPLES = 10        # samples a segment inside the search (the result is scaled to feasibility.py's 32)
SEGMENT_BISECTIONS = 14  # of each segment's own scale in the start (log k to 4e-4)
EQUALISE_ROUNDS = 1      # start: each segment scaled to its own limit, this many times
NEAR = 1.0               # (check, sample) pairs within NEAR x the trust radius of their limit enter the step
NEEDS_STEP = 1e-7        # step of the needs' directional derivative along a colour's change of a, j, snap
_ROOT_ITERATIONS = 60     # of the scale's root finding (Illinois), to _ROOT_TOLERANCE in log k
_ROOT_TOLERANCE = 1e-7
_SAFETY = 1.0 + 1e-7     # the returned scale a hair above the root finder's feasible end


class Constraints:
    """The margined limits of one vehicle as normalised per-sample violations (<= 0 feasible)."""

    def __init__(self, vehicle, margin=DEFAULT_MARGIN, samples_per_segment=feasibility.SAMPLES_PER_SEGMENT):
        self.vehicle = vehicle
        self.limits = feasibility.margined_limits(vehicle, margin)
        # tilt + lag x tilt rate >= tilt under the same limit: attitude_lag passing implies tilt passes
        del self.limits['tilt']
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
            hi, f0 = 1.0, float(w.max())
            while True:
                hi *= 1.0 + max(f0, 0.05)
                f1 = float(worst(hi, a, j, snap).max())
                if f1 <= 0.0:
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
            f0, f1 = float(w.max()), float(worst(hi, a, j, snap).max())

        def f(log_k):
            return float(worst(np.exp(log_k), a, j, snap).max())

        # Illinois regula falsi on the worst violation over log k (over the samples that fail at lo, whose
        # worst is the worst of all there): bracketing, so it converges like bisection at worst, and in a
        # handful of evaluations on this smooth, monotone function
        x0, x1 = np.log(lo), np.log(hi)
        side = 0
        for _ in range(_ROOT_ITERATIONS):
            # done when the bracket, or the secant's distance from the feasible end to the root, is below tolerance
            if x1 - x0 < _ROOT_TOLERANCE or -f1 * (x1 - x0) < _ROOT_TOLERANCE * (f0 - f1):
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


def _linearised_constraints(system, points, x, constraints, near, derivatives=None):
    """Rows v_r + J_r d <= 0 of every (check, sample) within `near` of its limit (v > -near), with J = dv/dx
    from one banded LU of the spline's system (_derivative_directions, or `derivatives` when given) and the
    needs' directional derivative along each colour's exact change of acceleration, jerk and snap; returns
    (J as BandRows, v_r). Every near sample is a row, not only each segment's peak: the peak moves between
    samples as the times change, and a programme that sees only the peaks steps into the samples it does not
    see."""
    m = x.size
    width = 2 * BAND + 1
    colours = min(width, m)
    if derivatives is None:
        derivatives = _derivative_directions(system, points, np.exp(x), _colours(m), constraints.s)
    (a, j, snap), (da, dj, ds) = derivatives
    v = constraints.violations(a, j, snap)
    active = v > -near
    segment = np.nonzero(active)[1]          # the segment of each row
    # every colour's perturbed needs in one evaluation: (checks, colours x m, S)
    moved = constraints.violations(*((value[None] + NEEDS_STEP * change).reshape(-1, *value.shape[1:])
                                     for value, change in ((a, da), (j, dj), (snap, ds))))
    moved = moved.reshape(v.shape[0], colours, m, -1)
    dv = (moved.transpose(1, 0, 2, 3)[:, active] - v[active]) / NEEDS_STEP       # (colours, rows)
    # the perturbed segment within BAND of each row's segment is the one congruent to the colour modulo
    # 2 BAND + 1: column segment - BAND + (colour - segment + BAND) mod (2 BAND + 1) of the row's band
    band = np.zeros((segment.size, width))
    band[np.arange(segment.size)[:, None], (np.arange(colours) - segment[:, None] + BAND) % width] = dv.T
    inside = segment[:, None] - BAND + np.arange(width)
    band[(inside < 0) | (inside >= m)] = 0.0
    return BandRows(band, segment, m), v[active]


def _colours(m):
    """The 2 BAND + 1 directions (fewer for a shorter plan) in x: colour c moves every segment c mod 2 BAND + 1."""
    width = 2 * BAND + 1
    directions = np.zeros((min(width, m), m))
    for colour in range(directions.shape[0]):
        directions[colour, colour::width] = 1.0
    return directions


def _scaled_derivatives(derivatives, k):
    """_derivative_directions' output at times k T from that at T: A depends on the times' ratios only, so y
    and dy/dx are the same, and derivative q (its value and its changes) divides by k^q."""
    (values, changes) = derivatives
    return (tuple(v / k ** q for v, q in zip(values, (2, 3, 4))), tuple(c / k ** q for c, q in zip(changes, (2, 3, 4))))


def _derivative_directions(system, points, T, directions, s):
    """Acceleration, jerk and snap (m, 3, S) of the spline with times T, and their derivatives along each row
    of `directions` (D, m) in x = log T: three arrays (D, m, 3, S).

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
    # every scaled entry of a continuity row belongs to that row's joint k, so dA y = u_r (dx_k+1 - dx_k) with
    # u = S y, S the entries' d val / d(x_k+1 - x_k) = p val
    scaled = system.scaled
    slope = csr_matrix((vals[scaled] * system.power[scaled], (rows[scaled], cols[scaled])), shape=(n_rows, n_rows))
    u = slope @ y
    joint_rows, first = np.unique(rows[scaled], return_index=True)
    k = system.joint[scaled][first]
    n_dir = directions.shape[0]
    rhs = np.zeros((n_rows, n_dir, 3))
    rhs[joint_rows] = -(directions[:, k + 1] - directions[:, k]).T[:, :, None] * u[joint_rows][:, None, :]
    dy, _ = dgbtrs(lu, lower, upper, rhs.reshape(n_rows, n_dir * 3), pivots)
    n = 2 * system.r
    s = np.asarray(s, dtype=float)
    y = y.reshape(system.m, n, 3)
    dy = dy.reshape(system.m, n, n_dir, 3)
    values, changes = [], []
    # one matrix product with each derivative's basis per direction: (D, m 3, n); a single (D m 3, n) product
    # is large enough for OpenBLAS to thread, which at 1000 segments cost 2.5x the CPU for the same result
    y_rows = y.transpose(0, 2, 1).reshape(-1, n)            # (m 3, n)
    dy_rows = dy.transpose(2, 0, 3, 1).reshape(n_dir, -1, n)
    for q in (2, 3, 4):
        if q >= n:
            basis = np.zeros((n, s.size))
        else:
            basis = np.zeros((n, s.size))
            basis[q:] = derivative_factors(n, q)[:, None] * s[None, :] ** np.arange(n - q)[:, None]
        scale = T[:, None, None] ** -q
        value = (y_rows @ basis).reshape(system.m, 3, s.size) * scale
        change = (dy_rows @ basis).reshape(n_dir, system.m, 3, s.size) * scale[None]
        values.append(value)
        changes.append(change - q * directions[:, :, None, None] * value[None])
    return tuple(values), tuple(changes)


class BandRows:
    """A sparse matrix whose row r is nonzero only in the 2 BAND + 1 columns segment_r - BAND ..
    segment_r + BAND: band (R, 2 BAND + 1) holds them (0 where a column falls outside 0..m-1). Products by
    CSR, and the normal matrix J^T diag(w) J in LAPACK's upper banded storage (bandwidth 2 BAND) as one sparse
    product with w."""

    def __init__(self, band, segment, m, columns=None):
        self.band, self.segment, self.m = band, segment, m
        # int32 indices: scipy's sparse constructors would otherwise check and convert int64 ones every time
        self._columns = (np.clip(segment[:, None] - BAND + np.arange(band.shape[1]), 0, m - 1).astype(np.int32)
                         if columns is None else columns)

    @property
    def shape(self):
        return self.band.shape[0], self.m

    def __getitem__(self, rows):
        return BandRows(self.band[rows], self.segment[rows], self.m, self._columns[rows])

    def toarray(self):
        return self.csr().toarray()

    def abs_row_sums(self):
        return np.abs(self.band).sum(axis=1)

    def csr(self):
        """J as CSR: every row its 2 BAND + 1 entries (those outside 0..m-1 are 0 at a clipped column)."""
        from scipy.sparse import csr_matrix

        rows, width = self.band.shape
        return csr_matrix((self.band.ravel(), self._columns.ravel(), np.arange(0, rows * width + 1, width,
                                                                                dtype=np.int32)), shape=self.shape)

    def normal_operator(self):
        """S with S w = J^T diag(w) J in upper banded storage (2 BAND + 1, m), flattened: entry
        N[c, c + k] = sum_r w_r J_rc J_r(c+k) sits at ab[2 BAND - k, c + k] (LAPACK's dpbtrf, upper).
        Built as a CSC matrix whose column r holds the products of row r's pairs of entries, diagonal by
        diagonal (k = 0 .. 2 BAND, p = 0 .. 2 BAND - k); a pair reaching outside 0..m-1 holds a 0 of the band,
        at a clipped index."""
        from scipy.sparse import csc_matrix

        rows, width = self.band.shape
        pairs = np.concatenate([self.band[:, :width - k] * self.band[:, k:] for k in range(width)], axis=1)
        offset = ((width - 1 - _PAIR_K) * self.m - BAND + _PAIR_P + _PAIR_K).astype(np.int32)
        flat = self.segment.astype(np.int32)[:, None] + offset[None, :]
        np.clip(flat, 0, width * self.m - 1, out=flat)
        return csc_matrix((pairs.ravel(), flat.ravel(), np.arange(0, rows * offset.size + 1, offset.size,
                                                                  dtype=np.int32)), shape=(width * self.m, rows))


# the normal matrix's column pairs (p, p + k) of a band row, diagonal k by diagonal
_PAIR_K, _PAIR_P = (np.concatenate(v) for v in zip(*[(np.full(2 * BAND + 1 - k, k), np.arange(2 * BAND + 1 - k))
                                                     for k in range(2 * BAND + 1)]))


def _lp_step(T, J, g, trust):
    """The step d: min sum_j T_j d_j s.t. g + J d <= 0, |d_j| <= trust, or None when no such d is found.

    Mehrotra's predictor-corrector interior-point method on A d <= H with A = [J; -I; I], H = [-g; trust; trust]:
    slacks y = H - A d and multipliers z (both > 0), residuals r_p = A d + y - H, r_d = T + A^T z. J is banded
    (BandRows), so each Newton system A^T diag(z / y) A dd = -r_d - A^T ((z r_p - r_c) / y) is a banded Cholesky of
    bandwidth 2 BAND, O(m BAND^2) however many rows (LAPACK dpbtrf/dpbtrs called directly: scipy's checking wrappers
    cost more than the factorisation at 100 segments). The step meets A dd + dy = -r_p and A^T dz = -r_d, so steps
    of primal and dual length a scale r_p and r_d by 1 - a. Stops when the residuals and the gap y.z are below
    LP_TOLERANCE of the problem's scale; None at once when a row lies beyond the box's reach, or when the gap grows
    DIVERGED-fold (rows that contradict each other: the multipliers grow unbounded)."""
    from scipy.linalg.lapack import dpbtrf, dpbtrs

    rows, m = J.shape
    if np.any(g - trust * J.abs_row_sums() > 0.0):     # a row that no d in the box brings inside
        return None
    csr, normal = J.csr(), J.normal_operator()
    csr_t = csr.T

    def a_dot(d):
        return np.concatenate([csr @ d, -d, d])

    def a_transpose_dot(z):
        return csr_t @ z[:rows] - z[rows:rows + m] + z[rows + m:]

    def newton(factor, r_dual, r_primal, r_comp):
        """(dd, dy, dz) of the Newton step with complementarity residual r_comp (of y z)."""
        dd, _ = dpbtrs(factor, -r_dual - a_transpose_dot((z * r_primal - r_comp) / y), lower=0)
        dy = -r_primal - a_dot(dd)
        return dd, dy, (-r_comp - z * dy) / y

    H = np.concatenate([-g, np.full(2 * m, trust)])
    cost_scale = float(np.abs(T).max())
    d = np.zeros(m)
    y = np.maximum(H, 0.0) + 0.1 * trust + 1e-3
    z = np.concatenate([np.zeros(rows), np.maximum(T, 0.0), np.maximum(-T, 0.0)]) + 0.1 * cost_scale
    primal_scale, dual_scale = 1.0 + float(np.abs(H).max()), 1.0 + cost_scale
    start_gap = None
    r_dual = T + a_transpose_dot(z)
    r_primal = a_dot(d) + y - H
    for _ in range(LP_ITERATIONS):
        gap = float(np.sum(y * z))     # sums, not BLAS dots: OpenBLAS threads a long dot (CPU for nothing)
        start_gap = start_gap or gap
        if not gap < DIVERGED * start_gap:     # the multipliers grow without bound: no d meets every row
            return None
        if (gap <= LP_TOLERANCE * (1.0 + abs(float(np.sum(T * d))))       # the gap first: the last to close
                and np.abs(r_primal).max() <= LP_TOLERANCE * primal_scale
                and np.abs(r_dual).max() <= LP_TOLERANCE * dual_scale):
            return d
        w = z / y
        ab = (normal @ w[:rows]).reshape(2 * BAND + 1, m)
        ab[-1] += w[rows:rows + m] + w[rows + m:]
        factor, info = dpbtrf(ab, lower=0)
        if info != 0:
            return None
        # predictor: the affine step; its gap sets the centring target sigma mu with sigma = (gap_affine / gap)^3
        dd, dy, dz = newton(factor, r_dual, r_primal, y * z)
        primal, dual = _longest(y, dy), _longest(z, dz)
        target = (float(np.sum((y + primal * dy) * (z + dual * dz))) / gap) ** 3 * gap / y.size
        # corrector: centred, with the predictor's second-order term
        dd, dy, dz = newton(factor, r_dual, r_primal, y * z + dy * dz - target)
        primal, dual = 0.995 * _longest(y, dy), 0.995 * _longest(z, dz)
        d, y, z = d + primal * dd, y + primal * dy, z + dual * dz
        r_primal, r_dual = (1.0 - primal) * r_primal, (1.0 - dual) * r_dual
    return None


def _longest(x, dx):
    """The longest step a <= 1 along dx that keeps x (> 0) non-negative: a <= x_i / -dx_i where dx_i < 0."""
    shrink = float(np.max(-dx / x))
    return 1.0 if shrink <= 1.0 else 1.0 / shrink


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
        for round_ in range(EQUALISE_ROUNDS + 1):
            trajectory = solve(T)
            candidate = T * constraints.feasible_scale(trajectory)
            if best is None or candidate.sum() < best.sum():
                best = candidate
            if round_ < EQUALISE_ROUNDS:
                T = T * constraints.segment_scales(trajectory)
    # the iterate T may sit slightly outside the limits (a step is kept for its scaled total, and the next
    # programme pulls its rows back inside); best is the shortest plan scaled to them so far, merit its total
    T = best
    merit = float(best.sum())
    trust = FIRST_TRUST
    J = derivatives = None
    for iteration in range(MAX_ITERATIONS):
        if trust < MIN_TRUST:
            break
        near = min(NEAR * trust, 1.0)
        if J is None:   # kept while steps from the same point are refused
            if derivatives is None:
                derivatives = _derivative_directions(system, points, T, _colours(T.size), constraints.s)
            J, g = _linearised_constraints(system, points, np.log(T), constraints, near, derivatives)
        # a row that no step inside the box can reach (g_r + trust |J_r|_1 <= 0) cannot bind: left out
        rows = g + trust * J.abs_row_sums() > 0.0
        d = _lp_step(T, J[rows], g[rows], trust)
        if d is None:
            if T is not best:      # no step within the radius pulls this iterate inside: back to the best
                derivatives = _scaled_derivatives(derivatives, merit / float(T.sum()))   # best is T scaled
                T, J = best, None
            else:
                trust *= SHRINK
            continue
        predicted = merit - float(T @ (1.0 + d))        # the time the linearised step saves
        if predicted < STALL_GAIN * merit:
            break
        shape = T * np.exp(d)
        candidate = shape * constraints.feasible_scale(solve(shape))
        actual = merit - float(candidate.sum())
        if log is not None:
            log(f'fastest: step {iteration}: trust {trust:.3g}, {merit:.4f} s -> {candidate.sum():.4f} s '
                f'(predicted {merit - predicted:.4f} s)')
        ratio = actual / predicted
        # the usual trust-region update on how well the linear model predicted the gain
        step = float(np.abs(d).max())
        if ratio < 0.25:
            trust = SHRINK * step
        elif ratio > GROW_RATIO and step > 0.99 * trust:
            trust = min(GROW * trust, 1.0)
        if ratio > 0.0:
            T, J, derivatives, best, merit = shape, None, None, candidate, float(candidate.sum())
            if actual < SETTLED_GAIN * merit:
                break
    T = best
    # the search samples LOOP_SAMPLES points a segment; the plan is checked (and flown) at feasibility.py's
    return T * Constraints(vehicle, margin).feasible_scale(solve(T))
