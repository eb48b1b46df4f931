"""Planning: time allocation, limits, control points, yaw, collisions, merging and every bad input."""

import dataclasses

import numpy as np
import pytest

from quad_common.vehicle import load_vehicle
from quad_common.world import World
from quad_trajectory import collision, feasibility, planner, timing
from quad_trajectory.mission import DEFAULT_VEHICLE_PATH
from quad_trajectory.planner import PlanOptions, plan
from quad_trajectory.polynomial import PiecewisePolynomial

WAYPOINTS = [[0, 0, 1], [1, 0, 1], [1, 1, 1.5], [3, 1, 1], [3, 3, 1]]
# a 1 cm wall at x = 2 with a gap |y| < 0.2; the path turns north right behind it
WALL_WORLD = World([-1, 5, -3, 3, 0, 3], [[2.0, 2.01, -3, -0.2, 0, 3], [2.0, 2.01, 0.2, 3, 0, 3]])
THROUGH_GAP = [[0, 0, 1], [2.2, 0, 1], [2.2, 2.5, 1]]


def dense(traj, rate_hz=2000.0):
    return traj.evaluate(np.linspace(0, traj.duration_s, int(traj.duration_s * rate_hz) + 2), 0)


def test_seed_speed_profile_formula():
    result = plan(WAYPOINTS, options=PlanOptions(speed_mps=0.5))
    lengths = np.linalg.norm(np.diff(np.asarray(WAYPOINTS, float), axis=0), axis=1)
    total = lengths.sum() / 0.5
    expected = total * np.sqrt(lengths) / np.sqrt(lengths).sum()
    np.testing.assert_allclose(result.trajectory.durations_s, expected, rtol=1e-12)
    assert result.trajectory.duration_s == pytest.approx(total)


def test_proportional_allocation_flies_each_leg_at_the_speed():
    result = plan(WAYPOINTS, options=PlanOptions(speed_mps=2.0, time_allocation='proportional'))
    lengths = np.linalg.norm(np.diff(np.asarray(WAYPOINTS, float), axis=0), axis=1)
    np.testing.assert_allclose(result.trajectory.durations_s, lengths / 2.0)


@pytest.mark.parametrize('method', ['minaccel', 'minjerk', 'minsnap'])
def test_limit_aware_timing_respects_and_reaches_the_limits(method):
    opts = PlanOptions(method=method, time_allocation='limits', v_max_mps=1.5, a_max_mps2=2.0, speed_mps=5.0)
    traj = plan(WAYPOINTS, options=opts).trajectory
    t = np.linspace(0, traj.duration_s, 50001)
    speed = np.linalg.norm(traj.evaluate(t, 1)[:, :3], axis=1).max()
    accel = np.linalg.norm(traj.evaluate(t, 2)[:, :3], axis=1).max()
    assert speed <= 1.5 and accel <= 2.0
    assert max(speed / 1.5, accel / 2.0) > 0.95   # as fast as the binding limit allows


def test_limit_defaults_come_from_the_vehicle_thrust_to_weight():
    vehicle = load_vehicle(DEFAULT_VEHICLE_PATH)
    a_max = timing.vehicle_acceleration_limit(vehicle.thrust_to_weight)
    assert a_max == pytest.approx(0.5 * 9.81 * (vehicle.thrust_to_weight - 1.0))
    traj = plan(WAYPOINTS, options=PlanOptions(time_allocation='limits', speed_mps=10.0), vehicle=vehicle).trajectory
    assert traj.max_acceleration() <= a_max * 1.001
    assert traj.max_speed() <= timing.DEFAULT_V_MAX_MPS * 1.001


def random_dense_mission(seed, n_legs=30):
    """n_legs legs of 0.4-1.2 m: random 3D directions, random planar ones, or near-reversals (zig-zag)."""
    rng = np.random.default_rng(seed)
    lengths = rng.uniform(0.4, 1.2, n_legs)
    kind = seed % 3
    if kind == 0:
        dirs = rng.normal(size=(n_legs, 3))
    elif kind == 1:
        dirs = np.column_stack([rng.normal(size=(n_legs, 2)), np.zeros(n_legs)])
    else:
        heading = np.cumsum(rng.uniform(2.0, 3.1, n_legs))
        dirs = np.column_stack([np.cos(heading), np.sin(heading), np.zeros(n_legs)])
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    return np.vstack([[0, 0, 1], np.cumsum(lengths[:, None] * dirs, axis=0) + [0, 0, 1]]), lengths.sum()


@pytest.mark.parametrize('seed', range(0, 300, 7))
def test_limits_allocation_converges_on_random_dense_missions(seed):
    """Issue: 30 short legs gave a 2.1e11 s, 2.1e11 m plan (seeds 11, 75, 197, 202, 285 of this family did)."""
    vehicle = load_vehicle(DEFAULT_VEHICLE_PATH)
    a_max = timing.vehicle_acceleration_limit(vehicle.thrust_to_weight)
    waypoints, polyline_m = random_dense_mission(seed)
    opts = PlanOptions(time_allocation='limits', speed_mps=[0.5, 2.0, 5.0][seed % 3],
                       control_points=(0.1, 0.9) if seed % 2 else ())
    traj = plan(waypoints, options=opts, vehicle=vehicle).trajectory
    assert traj.arc_length() <= 1.5 * polyline_m
    t = np.linspace(0, traj.duration_s, int(traj.duration_s * 2000) + 2)
    speed = np.linalg.norm(traj.evaluate(t, 1)[:, :3], axis=1).max()
    accel = np.linalg.norm(traj.evaluate(t, 2)[:, :3], axis=1).max()
    assert speed <= 1.05 * timing.DEFAULT_V_MAX_MPS and accel <= 1.05 * a_max
    assert feasibility.check(traj, vehicle).ok   # and the vehicle can fly it (tilt, thrust, rotors, lag)
    faster = time_scaled(traj, 1 / 1.1)          # not needlessly slow: a limit or the vehicle binds
    assert max(speed / timing.DEFAULT_V_MAX_MPS, accel / a_max) > 0.95 or not feasibility.check(faster, vehicle).ok


def time_scaled(traj, k):
    """The same path flown k times slower: p(t / k)."""
    n = traj.coefficients.shape[2]
    return PiecewisePolynomial(traj.durations_s * k, traj.coefficients / k ** np.arange(n))


def test_limits_allocation_is_never_slower_than_the_scaled_sqrt_shape():
    waypoints, _ = random_dense_mission(11)
    limits = plan(waypoints, options=PlanOptions(time_allocation='limits', a_max_mps2=4.0)).trajectory
    sqrt = plan(waypoints, options=PlanOptions(speed_mps=1.0)).trajectory
    v_max, a_max = 0.97 * timing.DEFAULT_V_MAX_MPS, 0.97 * 4.0
    k = max(sqrt.max_speed() / v_max, np.sqrt(sqrt.max_acceleration() / a_max))
    assert limits.duration_s <= k * sqrt.duration_s * (1 + 1e-9)


def test_an_absurd_plan_is_refused_not_returned():
    with pytest.raises(ValueError, match=r'absurd.*1 mm/s on average.*speed = 1e-06'):
        plan(WAYPOINTS, options=PlanOptions(speed_mps=1e-6))
    traj = plan(WAYPOINTS).trajectory
    stretched = PiecewisePolynomial(traj.durations_s, traj.coefficients * 100)  # a path 100x too long
    points = np.column_stack([np.asarray(WAYPOINTS, float), np.zeros(len(WAYPOINTS))])
    with pytest.raises(ValueError, match=r'absurd: .* x the .* polyline; at most 10 x'):
        planner.check_sane(stretched, points, PlanOptions())


def test_optimal_allocation_lowers_the_objective():
    base = plan(WAYPOINTS, options=PlanOptions())
    opt = plan(WAYPOINTS, options=PlanOptions(time_allocation='optimal'))
    from quad_trajectory import solver

    def objective(traj):
        return solver.derivative_cost(traj.durations_s, traj.coefficients, 4) / solver.derivative_cost(
            base.trajectory.durations_s, base.trajectory.coefficients, 4) + 7 * traj.duration_s / \
            base.trajectory.duration_s
    assert objective(opt.trajectory) < objective(base.trajectory) - 1e-3


def test_control_points_at_the_seed_fractions_are_passed_through():
    result = plan(WAYPOINTS, options=PlanOptions(control_points=(0.1, 0.9)))
    assert result.trajectory.n_segments == 3 * (len(WAYPOINTS) - 1)
    a, b = np.asarray(WAYPOINTS[0], float), np.asarray(WAYPOINTS[1], float)
    np.testing.assert_allclose(result.points[1:3, :3], [0.9 * a + 0.1 * b, 0.1 * a + 0.9 * b])
    np.testing.assert_allclose(result.trajectory.evaluate(result.waypoint_times_s())[:, :3], WAYPOINTS, atol=1e-9)
    np.testing.assert_allclose(result.trajectory.evaluate(result.trajectory.breaks_s), result.points, atol=1e-9)
    # closer to the straight legs than without them
    free = plan(WAYPOINTS)
    assert _max_leg_distance(result) < _max_leg_distance(free)


def _max_leg_distance(result):
    p = dense(result.trajectory)[:, :3]
    w = result.waypoints
    dists = []
    for a, b in zip(w[:-1], w[1:]):
        s = np.clip((p - a) @ (b - a) / ((b - a) @ (b - a)), 0, 1)
        dists.append(np.linalg.norm(p - (a + s[:, None] * (b - a)), axis=1))
    return np.min(dists, axis=0).max()


def test_yaw_per_waypoint_is_unwrapped_and_constant_yaw_stays():
    result = plan([[0, 0, 1], [1, 0, 1], [2, 0, 1]], yaw=[3.0, -3.0, 3.0])
    np.testing.assert_allclose(result.yaw, [3.0, 2 * np.pi - 3.0, 3.0])   # the short way round, +0.28 rad
    yaw = result.trajectory.evaluate(np.linspace(0, result.trajectory.duration_s, 500))[:, 3]
    assert yaw.min() > 2.9 and yaw.max() < 3.4
    constant = plan(WAYPOINTS, yaw=0.7).trajectory.evaluate(np.linspace(0, 10, 50))[:, 3]
    np.testing.assert_allclose(constant, 0.7, atol=1e-9)


def test_sampled_trajectory_and_json_round_trip():
    traj = plan(WAYPOINTS).trajectory
    sampled = traj.to_sampled(100.0)
    assert sampled.times_s[-1] == pytest.approx(traj.duration_s)
    t = np.linspace(0, traj.duration_s, 777)
    np.testing.assert_allclose(sampled.evaluate(t, order=2)[0], traj.evaluate(t), atol=1e-6)
    again = PiecewisePolynomial.from_dict(traj.to_dict())
    np.testing.assert_array_equal(again.coefficients, traj.coefficients)
    assert traj.arc_length() == pytest.approx(np.linalg.norm(np.diff(dense(traj)[:, :3], axis=0), axis=1).sum(),
                                              rel=1e-5)


# --- collisions ------------------------------------------------------------------------------

def test_thin_wall_is_never_skipped_at_speed():
    world = World([-1, 50, -1, 1, 0, 2], [[20.0, 20.01, -1, 1, 0, 2]])
    fast = PiecewisePolynomial([1.0], [[[0, 40.0, 0, 0], [0, 0, 0, 0], [1, 0, 0, 0], [0, 0, 0, 0]]])  # 40 m/s
    segments, times = collision.trajectory_collisions(world, fast, radius_m=0.0)
    assert segments.tolist() == [0]
    assert times.min() == pytest.approx(0.5, abs=1e-3)


def test_wall_and_gap_replanning_inserts_points_until_collision_free():
    opts = PlanOptions(robot_radius_m=0.1, speed_mps=1.0, avoid_collisions=False)
    with pytest.raises(ValueError, match='collides'):
        plan(THROUGH_GAP, options=opts, world=WALL_WORLD)
    result = plan(THROUGH_GAP, options=dataclasses.replace(opts, avoid_collisions=True), world=WALL_WORLD)
    assert result.inserted_points > 0
    assert result.trajectory.n_segments == 2 + result.inserted_points
    assert not WALL_WORLD.collides(dense(result.trajectory, 5000)[:, :3], 0.1).any()
    np.testing.assert_allclose(result.trajectory.evaluate(result.waypoint_times_s())[:, :3], THROUGH_GAP, atol=1e-9)


def test_waypoints_through_an_obstacle_cannot_be_planned():
    with pytest.raises(ValueError, match=r'straight leg \[0.0, 1.0, 1.0\] -> \[4.0, 1.0, 1.0\]'):
        plan([[0, 1, 1], [4, 1, 1]], options=PlanOptions(robot_radius_m=0.1), world=WALL_WORLD)


# --- input validation ------------------------------------------------------------------------

def test_close_waypoints_are_merged_and_reported():
    w = [[0, 0, 1], [0.0004, 0, 1], [1, 0, 1], [1, 0.0009, 1], [1, 1, 1]]
    result = plan(w)
    assert result.trajectory.n_segments == 2
    assert [(m.index, m.into_index) for m in result.merged] == [(1, 0), (3, 2)]
    assert result.merged[0].distance_m == pytest.approx(0.0004)
    assert 'waypoint 1 merged into waypoint 0' in str(result.merged[0])
    assert result.to_dict()['merged'][1]['index'] == 3


@pytest.mark.parametrize('kwargs,words', [
    ({'waypoints': [[0, 0, 1]]}, 'at least two distinct'),
    ({'waypoints': [[0, 0, 1], [0, 0, 1.0005]]}, 'at least two distinct'),
    ({'waypoints': [[0, 0, 1], [1, float('nan'), 1]]}, r'waypoints\[1\] = \[1.0, nan, 1.0\] must be finite'),
    ({'waypoints': [[0, 0, 1], [1, 0, float('inf')]]}, r'waypoints\[1\]'),
    ({'waypoints': [[0, 0], [1, 0]]}, r'waypoints\[0\] = \[0, 0\] must be \[x, y, z\]'),
    ({'waypoints': 'here'}, "waypoints = 'here' must be a list of \\[x, y, z\\]"),
    ({'speed_mps': 0.0}, 'speed = 0.0 must be'),
    ({'speed_mps': -1.0}, 'speed = -1.0'),
    ({'speed_mps': float('nan')}, 'speed = nan'),
    ({'method': 'minpop'}, "method = 'minpop' must be one of minaccel, minjerk, minsnap"),
    ({'waypoint_constraint': 'zero'}, "waypoint_constraint = 'zero'"),
    ({'time_allocation': 'fast'}, "time_allocation = 'fast'"),
    ({'v_max_mps': 0.0, 'time_allocation': 'limits'}, 'limits.v_max_mps = 0.0'),
    ({'a_max_mps2': 50.0, 'time_allocation': 'limits'}, 'limits.a_max_mps2 = 50.0 cannot be met'),
    ({'control_points': (0.1, 1.5)}, 'control_points'),
    ({'yaw': [0.0, 1.0]}, 'yaw = \\[0.0, 1.0\\] must be one number or one per waypoint'),
])
def test_bad_input_names_field_and_value(kwargs, words):
    waypoints = kwargs.pop('waypoints', WAYPOINTS)
    yaw = kwargs.pop('yaw', None)
    with pytest.raises(ValueError, match=words):
        plan(waypoints, yaw, PlanOptions(**kwargs), vehicle=load_vehicle(DEFAULT_VEHICLE_PATH))


def test_limits_without_acceleration_limit_or_vehicle_is_refused():
    with pytest.raises(ValueError, match='limits.a_max_mps2 or a vehicle'):
        planner.plan(WAYPOINTS, options=PlanOptions(time_allocation='limits'))
