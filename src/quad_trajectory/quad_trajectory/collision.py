"""Collision checks of paths and trajectories against a World with a robot radius.

Samples are spaced at most `spacing_m` apart along the path (per segment: peak speed x duration /
spacing samples), so with the default 5 mm no obstacle thicker than 5 mm (a 1 cm wall) can fall
between two samples, at any speed.
"""

import numpy as np

from quad_common.world import World
from quad_trajectory.polynomial import PiecewisePolynomial

DEFAULT_SPACING_M = 0.005
_CHUNK = 20000


def colliding_mask(world: World, points, radius_m: float) -> np.ndarray:
    """world.collides in chunks, so that long trajectories in worlds with many blocks stay small in memory."""
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    return np.concatenate([world.collides(p[i:i + _CHUNK], radius_m) for i in range(0, len(p), _CHUNK)] or
                          [np.zeros(0, dtype=bool)])


def _fractions(counts):
    """Per group g, counts[g] (>= 2) evenly spaced values 0..1, concatenated; and each value's group."""
    group = np.repeat(np.arange(len(counts)), counts)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    return group, (np.arange(group.size) - starts[group]) / (counts[group] - 1)


def _indices(hits, n: int) -> np.ndarray:
    """Sorted distinct values of `hits` in [0, n): np.unique's result without its import of numpy.ma (0.1 s)."""
    return np.flatnonzero(np.bincount(hits, minlength=n))


def polyline_collisions(world: World, points, radius_m: float, spacing_m=DEFAULT_SPACING_M) -> np.ndarray:
    """Indices i of straight legs points[i] -> points[i+1] that come within radius_m of an obstacle."""
    p = np.asarray(points, dtype=float)[:, :3]
    lengths = np.linalg.norm(np.diff(p, axis=0), axis=1)
    counts = np.ceil(lengths / spacing_m).astype(int) + 2
    leg, frac = _fractions(counts)
    samples = p[leg] + frac[:, None] * (p[leg + 1] - p[leg])
    return _indices(leg[colliding_mask(world, samples, radius_m)], len(lengths))


def trajectory_collisions(world: World, traj: PiecewisePolynomial, radius_m: float,
                          spacing_m=DEFAULT_SPACING_M):
    """(indices of colliding segments, times in s of colliding samples)."""
    counts = np.ceil(traj.segment_peaks(1) * traj.durations_s / spacing_m).astype(int) + 2
    seg, frac = _fractions(counts)
    tau = frac * traj.durations_s[seg]
    hit = colliding_mask(world, traj.evaluate_local(seg, tau, 0)[:, :3], radius_m)
    return _indices(seg[hit], traj.n_segments), traj.breaks_s[seg[hit]] + tau[hit]
