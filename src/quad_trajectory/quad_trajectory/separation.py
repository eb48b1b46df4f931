"""Separation between planned trajectories over time (numpy only): the pairwise check before a fleet flies, and
a greedy deconfliction that tries candidates (start delays, altitude layers) one vehicle at a time.

Vehicle i flies trajectory_i(t - delay_i): it waits at its start before delay_i and holds its end after it.

Sample step: the distance d_ij(t) = |p_i(t) - p_j(t)| changes at most as fast as the relative speed,
|d_ij'| <= v_i + v_j (v the planned peak speeds), so between samples dt apart d_ij is never more than
(v_i + v_j) dt / 2 below the nearer sample. With dt = 2 tolerance / (v_1 + v_2), v_1 and v_2 the two largest
peak speeds of the fleet, the sampled minimum is within `tolerance_m` (5 mm, collision.DEFAULT_SPACING_M) of
the true one for every pair; the closest sample of each pair in conflict is then refined on a 100x finer grid.
"""

from dataclasses import dataclass, field

import numpy as np

DEFAULT_TOLERANCE_M = 0.005
MAX_STEP_S = 0.1           # the step when nothing moves (all peak speeds ~0)
_REFINE = 201              # samples over [t - dt, t + dt] when refining a pair's closest approach


@dataclass
class Conflict:
    """Vehicles a and b closer than required_m: the closest approach (time_s, distance_m), first below at first_s."""
    a: str
    b: str
    time_s: float
    distance_m: float
    required_m: float
    first_s: float

    def __str__(self):
        return (f'{self.a} and {self.b} come {self.distance_m:.3f} m apart at t = {self.time_s:.2f} s '
                f'(minimum separation {self.required_m:.3f} m; closer than that from t = {self.first_s:.2f} s)')


@dataclass
class SeparationReport:
    names: list
    step_s: float
    horizon_s: float
    distance_m: np.ndarray           # (N, N) closest approach of each pair (inf on the diagonal)
    time_s: np.ndarray               # (N, N) when it happens
    required_m: np.ndarray           # (N, N) minimum separation of each pair
    conflicts: list = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.conflicts

    @property
    def closest(self) -> tuple:
        """(a, b, distance_m, time_s) of the fleet's closest pair; None for one vehicle."""
        if len(self.names) < 2:
            return None
        i, j = np.unravel_index(np.argmin(self.distance_m), self.distance_m.shape)
        return self.names[i], self.names[j], float(self.distance_m[i, j]), float(self.time_s[i, j])


def step_for(max_speeds_mps, tolerance_m: float = DEFAULT_TOLERANCE_M) -> float:
    """dt = 2 tolerance / (v_1 + v_2), the two largest peak speeds (module docstring)."""
    v = np.sort(np.asarray(max_speeds_mps, dtype=float))[::-1]
    v_sum = float(v[:2].sum()) if v.size >= 2 else float(v.sum())
    return min(MAX_STEP_S, 2.0 * tolerance_m / v_sum) if v_sum > 0 else MAX_STEP_S


def positions(trajectories, delays_s, times_s) -> np.ndarray:
    """(T, N, 3): vehicle i at trajectory_i(t - delay_i), held at its ends."""
    return np.stack([traj.evaluate(np.asarray(times_s) - d, 0)[:, :3] for traj, d in zip(trajectories, delays_s)],
                    axis=1)


def required_matrix(radii_m, margin_m: float, min_m: float | None = None) -> np.ndarray:
    """Minimum separation of each pair: min_m when given, else r_i + r_j + margin_m."""
    r = np.asarray(radii_m, dtype=float)
    req = np.full((r.size, r.size), float(min_m)) if min_m is not None else r[:, None] + r[None, :] + margin_m
    np.fill_diagonal(req, 0.0)
    return req


def _grid(trajectories, delays_s, tolerance_m):
    step = step_for([t.max_speed() for t in trajectories], tolerance_m)
    horizon = max(float(d) + t.duration_s for t, d in zip(trajectories, delays_s))
    n = int(np.ceil(horizon / step)) + 1
    return step, horizon, np.arange(n) * step


def _refine(ti, tj, di, dj, t_s, step_s):
    """(time, distance) of the closest approach of two vehicles near t_s, on a grid 100x finer than step_s."""
    t = np.linspace(t_s - step_s, t_s + step_s, _REFINE)
    d = np.linalg.norm(ti.evaluate(t - di, 0)[:, :3] - tj.evaluate(t - dj, 0)[:, :3], axis=1)
    k = int(np.argmin(d))
    return float(t[k]), float(d[k])


def check(trajectories, names, delays_s, required_m, tolerance_m: float = DEFAULT_TOLERANCE_M,
          only=None) -> SeparationReport:
    """Every pair (or, with only = k, vehicle k against those before it) over the common time grid; a pair
    closer than required_m[i, j] at any sample is a Conflict, with its refined closest approach."""
    n = len(trajectories)
    delays_s = np.asarray(delays_s, dtype=float)
    step, horizon, t = _grid(trajectories, delays_s, tolerance_m)
    dist = np.full((n, n), np.inf)
    when = np.zeros((n, n))
    conflicts = []
    if n >= 2:
        p = positions(trajectories, delays_s, t)
        rows = range(n - 1) if only is None else [only]
        for i in rows:
            others = np.arange(i + 1, n) if only is None else np.arange(i)
            if others.size == 0:
                continue
            d = np.linalg.norm(p[:, others] - p[:, i:i + 1], axis=2)     # (T, len(others))
            k = np.argmin(d, axis=0)
            for col, j in enumerate(others):
                a, b = min(i, j), max(i, j)
                dist[a, b] = dist[b, a] = d[k[col], col]
                when[a, b] = when[b, a] = t[k[col]]
                below = d[:, col] < required_m[i, j]
                if below.any():
                    tc, dc = _refine(trajectories[a], trajectories[b], delays_s[a], delays_s[b], t[k[col]], step)
                    dist[a, b] = dist[b, a] = min(dc, dist[a, b])
                    when[a, b] = when[b, a] = tc
                    conflicts.append(Conflict(names[a], names[b], tc, dist[a, b], float(required_m[a, b]),
                                              float(t[np.argmax(below)])))
    conflicts.sort(key=lambda c: c.distance_m)
    return SeparationReport(list(names), step, horizon, dist, when, required_m, conflicts)


def deconflict(trajectories, names, delays_s, required_m, candidates, tolerance_m: float = DEFAULT_TOLERANCE_M):
    """Greedy deconfliction in the fleet's order: vehicle k keeps its plan if it is clear of vehicles 0..k-1 as
    already placed, else takes the first of candidates(k) (an iterable of (trajectory, delay_s, description))
    that is. Returns (trajectories, delays, changes: one line per vehicle changed). Raises ValueError naming the
    vehicle and its closest conflict when no candidate is clear."""
    trajectories, delays = list(trajectories), [float(d) for d in delays_s]
    changes = []
    for k in range(1, len(trajectories)):
        report = check(trajectories[:k + 1], names[:k + 1], delays[:k + 1], required_m[:k + 1, :k + 1],
                       tolerance_m, only=k)
        if report.ok:
            continue
        worst = report.conflicts[0]
        for traj, delay, description in candidates(k):
            trial_t, trial_d = trajectories[:k] + [traj], delays[:k] + [delay]
            if check(trial_t, names[:k + 1], trial_d, required_m[:k + 1, :k + 1], tolerance_m, only=k).ok:
                trajectories[k], delays[k] = traj, delay
                changes.append(f'{names[k]}: {description} (was: {worst})')
                break
        else:
            raise ValueError(f'deconfliction found no clear candidate for {names[k]}: {worst}')
    return trajectories, delays, changes
