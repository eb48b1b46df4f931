"""The seed's linear system A c = b for minimum-derivative splines, and its O(M) banded solution.

A segment of order-r minimum (r = 2 acceleration, 3 jerk, 4 snap) is a polynomial of degree 2r-1,
2r coefficients per axis, written in normalised time s = tau / T in [0, 1] while solving (this keeps
A well conditioned whatever the segment durations) and returned in powers of local time tau.

Rows, 2r per segment (the seed's sections 3.2 and 3.3):
- start: p(0) = p_0 and derivatives 1..r-1 zero; end: the same at the last point;
- each inner waypoint i, mode `continuity`: p_{i-1}(T) = p_i = p_i(0) and derivatives 1..2r-2 equal
  on both sides. This is the exact minimiser of sum_i int |p_i^(r)|^2 dt for the given times (its
  Euler-Lagrange equation p^(2r) = 0 makes the optimum a degree 2r-1 spline with C^(2r-2) joints);
- each inner waypoint i, mode `stop`: both sides at p_i with derivatives 1..r-1 zero (rest at every point).

Ordering unknowns segment by segment and rows waypoint by waypoint, a row touches only the two
segments beside its waypoint, so A is banded with bandwidth < 3r: LAPACK's banded LU (gbsv) solves
it in O(M). `solve_dense_reference` is the seed's x = A^-1 b on the same rows, kept as the reference.
"""

from math import factorial

import numpy as np

from quad_trajectory.plan_inputs import MODES, ORDERS  # noqa: F401  (ORDERS: solver.ORDERS, as its callers name it)
from quad_trajectory.polynomial import derivative_factors


def _boundary_rows(n_coef: int):
    """D0[j] and D1[j]: coefficients of d^j/ds^j at s = 0 and s = 1 (j = 0..n_coef-1)."""
    d0 = np.zeros((n_coef, n_coef))
    d1 = np.zeros((n_coef, n_coef))
    for j in range(n_coef):
        d0[j, j] = factorial(j)
        d1[j, j:] = derivative_factors(n_coef, j)
    return d0, d1


def _inner_block(r: int, mode: str):
    """Rows of one inner waypoint: list of (terms, rhs_is_point); term = (side 0 left/1 right, j, at_end, sign)."""
    if mode == 'continuity':
        rows = [([(0, 0, True, 1.0)], True)]
        rows += [([(0, j, True, 1.0), (1, j, False, -1.0)], False) for j in range(1, 2 * r - 1)]
        rows += [([(1, 0, False, 1.0)], True)]
    else:
        rows = [([(0, j, True, 1.0)], j == 0) for j in range(r)]
        rows += [([(1, j, False, 1.0)], j == 0) for j in range(r)]
    return rows


# Up to this many unknowns (2rM) numpy's dense LU is as fast as the banded one and spares the import of
# scipy.linalg (~0.15 s of CPU, most of a small plan's run time).
DENSE_MAX_UNKNOWNS = 512


class System:
    """The rows of A for m segments, order r and a waypoint mode, assembled once; only the continuity rows'
    factors (T_right / T_left)^j depend on the times, so `triplets(T)` costs one vectorised power per solve
    (the time allocations solve the same points with many different times)."""

    def __init__(self, m: int, r: int, mode: str):
        if mode not in MODES:
            raise ValueError(f'waypoint_constraint = {mode!r} must be one of {", ".join(MODES)}')
        self.m, self.r, n = m, r, 2 * r
        d0, d1 = _boundary_rows(n)
        rows, cols, vals, joint, power, point_rows, point_index = [], [], [], [], [], [], []

        def add(row, col0, coef, scale_power=0):
            nz = np.nonzero(coef)[0]
            rows.append(np.repeat(row, nz.size))
            cols.append((col0[:, None] + nz[None, :]).reshape(-1))
            vals.append(np.tile(coef[nz], np.size(row)))
            joint.append(np.repeat(row * 0 + (col0 // n if scale_power else -1), nz.size))
            power.append(np.full(np.size(row) * nz.size, scale_power))

        one = np.zeros(1, dtype=int)
        for j in range(r):  # start block: rows 0..r-1
            add(np.array([j]), one, d0[j])
        point_rows.append([0])
        point_index.append([0])
        inner = np.arange(1, m)
        for q, (terms, rhs_is_point) in enumerate(_inner_block(r, mode)):
            row = r + (inner - 1) * n + q
            for side, j, at_end, sign in terms:
                coef = sign * (d1[j] if at_end else d0[j])
                # continuity: d^j/ds^j of the left segment scaled by (T_right / T_left)^j
                scaled = at_end and j > 0 and len(terms) > 1
                add(row, (inner - 1 + side) * n, coef, j if scaled else 0)
            if rhs_is_point:
                point_rows.append(row)
                point_index.append(inner)
        for j in range(r):  # end block
            add(np.array([n * m - r + j]), np.array([(m - 1) * n]), d1[j])
        point_rows.append([n * m - r])
        point_index.append([m])
        self.rows, self.cols = np.concatenate(rows), np.concatenate(cols)
        self.base = np.concatenate(vals)
        self.joint, self.power = np.concatenate(joint), np.concatenate(power)
        self.scaled = np.nonzero(self.power)[0]
        self.point_rows, self.point_index = np.concatenate(point_rows), np.concatenate(point_index)
        self.lower = int(np.max(self.rows - self.cols))
        self.upper = int(np.max(self.cols - self.rows))
        self._band_rows = self.upper + self.rows - self.cols

    def triplets(self, durations_s):
        """(rows, cols, vals) of A for these segment times."""
        T = np.asarray(durations_s, dtype=float)
        vals = self.base.copy()
        k = self.joint[self.scaled]
        vals[self.scaled] *= (T[k + 1] / T[k]) ** self.power[self.scaled]
        return self.rows, self.cols, vals

    def rhs(self, points) -> np.ndarray:
        P = np.asarray(points, dtype=float)
        b = np.zeros((2 * self.r * self.m, P.shape[1]))
        b[self.point_rows] = P[self.point_index]
        return b

    def solve(self, durations_s, points, banded: bool | None = None) -> np.ndarray:
        """Coefficients (M, K, 2r) in powers of local time: banded LU (dense LU when A is small, unless banded)."""
        T = np.asarray(durations_s, dtype=float)
        rows, cols, vals = self.triplets(T)
        b = self.rhs(points)
        if (b.shape[0] <= DENSE_MAX_UNKNOWNS) if banded is None else not banded:
            a = np.zeros((b.shape[0], b.shape[0]))
            a[rows, cols] = vals
            return _to_time_powers(np.linalg.solve(a, b), T, self.r)
        from scipy.linalg import solve_banded

        ab = np.zeros((self.lower + self.upper + 1, b.shape[0]))
        ab[self._band_rows, cols] = vals
        x = solve_banded((self.lower, self.upper), ab, b, overwrite_ab=True, overwrite_b=True, check_finite=False)
        return _to_time_powers(x, T, self.r)


def assemble(durations_s, points, r: int, mode: str):
    """Sparse triplets (rows, cols, vals) of A (size 2rM) and the right-hand side b (2rM, K)."""
    T = np.asarray(durations_s, dtype=float)
    system = System(T.size, r, mode)
    return (*system.triplets(T), system.rhs(points))


def _to_time_powers(x, durations_s, r):
    """Normalised-time solution (2rM, K) -> coefficients (M, K, 2r) in powers of local time."""
    m, n = durations_s.size, 2 * r
    c = x.reshape(m, n, -1).transpose(0, 2, 1)
    return c / durations_s[:, None, None] ** np.arange(n)[None, None, :]


def solve_banded_coefficients(durations_s, points, r: int, mode: str) -> np.ndarray:
    """O(M): banded LU of A (dense LU when A is small). Returns coefficients (M, K, 2r) in powers of local time."""
    T = np.asarray(durations_s, dtype=float)
    return System(T.size, r, mode).solve(T, points)


def solve_dense_reference(durations_s, points, r: int, mode: str) -> np.ndarray:
    """The seed's formulation x = A^-1 b with a dense inverse: O(M^3), a reference for tests and benchmarks only."""
    T = np.asarray(durations_s, dtype=float)
    rows, cols, vals, b = assemble(T, points, r, mode)
    a = np.zeros((b.shape[0], b.shape[0]))
    a[rows, cols] = vals
    return _to_time_powers(np.linalg.inv(a) @ b, T, r)


def derivative_cost_matrix(duration_s: float, n_coef: int, order: int) -> np.ndarray:
    """Q with c^T Q c = int_0^T (d^order p / dtau^order)^2 dtau for p = sum c_k tau^k."""
    q = np.zeros((n_coef, n_coef))
    f = np.zeros(n_coef)
    f[order:] = derivative_factors(n_coef, order)
    for i in range(order, n_coef):
        for k in range(order, n_coef):
            power = i + k - 2 * order + 1
            q[i, k] = f[i] * f[k] * duration_s ** power / power
    return q


def derivative_cost(durations_s, coefficients, order: int) -> float:
    """sum over segments and x, y, z of int |p^(order)|^2 dt (the snap cost for order 4)."""
    total = 0.0
    n = coefficients.shape[2]
    for T, c in zip(durations_s, coefficients):
        q = derivative_cost_matrix(T, n, order)
        total += float(np.einsum('ak,kl,al->', c[:3], q, c[:3]))
    return total
