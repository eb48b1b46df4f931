"""The minimum-derivative solver: constraints hold, continuity to the claimed order, banded == dense seed
formulation, and the continuity min-snap is the true minimiser of the snap cost (a direct QP)."""

import numpy as np
import pytest

from quad_trajectory import solver
from quad_trajectory.planner import solve

CASES = [(m, mode) for m in solver.ORDERS for mode in solver.MODES]


def random_problem(m, seed=0):
    rng = np.random.default_rng(seed)
    points = np.cumsum(rng.normal(size=(m + 1, 4)), axis=0)
    return points, rng.uniform(0.4, 3.0, m)


def jumps(traj, order):
    """|left - right| of derivative `order` at each inner break: (M-1, 4)."""
    m = traj.n_segments
    left = traj.evaluate_local(np.arange(m - 1), traj.durations_s[:-1], order)
    right = traj.evaluate_local(np.arange(1, m), np.zeros(m - 1), order)
    return np.abs(left - right)


@pytest.mark.parametrize('method,mode', CASES)
def test_waypoints_hit_and_rest_at_the_ends(method, mode):
    points, durations = random_problem(7)
    traj = solve(points, durations, method, mode)
    r = solver.ORDERS[method]
    assert traj.degree == 2 * r - 1
    np.testing.assert_allclose(traj.evaluate(traj.breaks_s), points, atol=1e-9)
    for order in range(1, r):
        np.testing.assert_allclose(traj.evaluate([0.0, traj.duration_s], order), 0.0, atol=1e-9)


@pytest.mark.parametrize('method', solver.ORDERS)
def test_continuity_mode_is_smooth_to_2r_minus_2_and_not_beyond(method):
    points, durations = random_problem(6, seed=1)
    traj = solve(points, durations, method, 'continuity')
    r = solver.ORDERS[method]
    for order in range(2 * r - 1):
        scale = np.abs(traj.evaluate(traj.breaks_s, order)).max() + 1.0
        assert jumps(traj, order).max() < 1e-8 * scale, order
    assert jumps(traj, 2 * r - 1).max() > 1e-3   # the (2r-1)th derivative is piecewise constant: it jumps


@pytest.mark.parametrize('method', solver.ORDERS)
def test_stop_mode_rests_at_every_waypoint_and_is_not_smoother(method):
    points, durations = random_problem(5, seed=2)
    traj = solve(points, durations, method, 'stop')
    r = solver.ORDERS[method]
    for order in range(1, r):
        np.testing.assert_allclose(traj.evaluate(traj.breaks_s, order), 0.0, atol=1e-9)
    assert jumps(traj, r).max() > 1e-3   # e.g. snap jumps at the waypoints for minsnap stop


@pytest.mark.parametrize('m', [1, 2, 10, 50])
@pytest.mark.parametrize('method,mode', CASES)
def test_banded_solver_equals_dense_seed_inverse(m, method, mode):
    points, durations = random_problem(m, seed=m)
    r = solver.ORDERS[method]
    banded = solver.solve_banded_coefficients(durations, points, r, mode)
    dense = solver.solve_dense_reference(durations, points, r, mode)
    assert np.abs(banded - dense).max() <= 1e-9 * np.abs(dense).max()


def test_continuity_minsnap_is_the_snap_qp_optimum():
    """Direct minimisation of sum int |p''''|^2 over 7th-order pieces, with only position, C3 joints and
    rest-to-rest ends imposed (KKT system); the seed's C6 continuity system must give the same curve."""
    points, durations = random_problem(5, seed=3)
    m, n, r = len(durations), 8, 4
    q = np.zeros((m * n, m * n))
    for i, T in enumerate(durations):
        q[i * n:(i + 1) * n, i * n:(i + 1) * n] = solver.derivative_cost_matrix(T, n, r)

    def row(i, order, tau):
        a = np.zeros(m * n)
        k = np.arange(order, n)
        a[i * n + k] = [np.prod(np.arange(kk - order + 1, kk + 1)) * tau ** (kk - order) for kk in k]
        return a

    rows, rhs = [], []
    for j in range(r):  # ends
        rows += [row(0, j, 0.0), row(m - 1, j, durations[-1])]
        rhs += [points[0], points[-1]] if j == 0 else [np.zeros(4), np.zeros(4)]
    for i in range(1, m):  # position at waypoints, C3 joints
        rows += [row(i - 1, 0, durations[i - 1]), row(i, 0, 0.0)]
        rhs += [points[i], points[i]]
        for j in range(1, r):
            rows.append(row(i - 1, j, durations[i - 1]) - row(i, j, 0.0))
            rhs.append(np.zeros(4))
    a, b = np.array(rows), np.array(rhs)
    kkt = np.block([[2 * q, a.T], [a, np.zeros((len(a), len(a)))]])
    x = np.linalg.solve(kkt, np.vstack([np.zeros((m * n, 4)), b]))[:m * n]
    qp = x.reshape(m, n, 4).transpose(0, 2, 1)
    ours = solver.solve_banded_coefficients(durations, points, r, 'continuity')
    t = np.linspace(0, durations.sum(), 500)
    from quad_trajectory.polynomial import PiecewisePolynomial
    np.testing.assert_allclose(PiecewisePolynomial(durations, ours).evaluate(t),
                               PiecewisePolynomial(durations, qp).evaluate(t), atol=1e-7)
    assert solver.derivative_cost(durations, ours, 4) == pytest.approx(solver.derivative_cost(durations, qp, 4),
                                                                       rel=1e-8)


def test_snap_cost_matrix_matches_numeric_integral():
    c = np.array([0.3, -1, 2, 0.5, -0.2, 0.1, 0.03, -0.01])
    T = 1.7
    q = solver.derivative_cost_matrix(T, 8, 4)
    t = np.linspace(0, T, 20001)
    snap = np.polyval(np.polyder(c[::-1], 4), t)
    assert c @ q @ c == pytest.approx(np.trapezoid(snap ** 2, t), rel=1e-6)


def test_unknown_mode_is_named():
    with pytest.raises(ValueError, match="waypoint_constraint = 'zero'"):
        solver.assemble([1.0], np.zeros((2, 4)), 4, 'zero')
