"""Piecewise-polynomial trajectory over the axes (x, y, z, yaw).

Segment i lasts durations_s[i]; on it each axis is sum_k c[i, axis, k] * tau^k with tau the local
time in [0, durations_s[i]] (ascending powers, the plan JSON layout of docs/design.md).
"""

import numpy as np
from scipy.special import roots_legendre

from quad_common.sampled_trajectory import SampledTrajectory

AXES = ('x', 'y', 'z', 'yaw')
_PEAK_SAMPLES_PER_SEGMENT = 128
# arc length: composite Gauss-Legendre, 16 pieces x 5 nodes per segment (the speed |v| has kinks where v = 0)
_PIECES = 16
_NODES, _WEIGHTS = roots_legendre(5)
_GAUSS_NODES = ((np.arange(_PIECES)[:, None] + 0.5 * (_NODES[None, :] + 1.0)) / _PIECES).reshape(-1)  # in [0, 1]
_GAUSS_WEIGHTS = np.tile(_WEIGHTS / (2 * _PIECES), _PIECES)                                          # sum to 1


def derivative_factors(n_coef: int, order: int) -> np.ndarray:
    """k! / (k - order)! for k = order .. n_coef-1: the d^order/dtau^order of tau^k is that times tau^(k-order)."""
    k = np.arange(order, n_coef)
    f = np.ones(k.size)
    for m in range(order):
        f *= k - m
    return f


class PiecewisePolynomial:
    def __init__(self, durations_s, coefficients):
        self.durations_s = np.asarray(durations_s, dtype=float).reshape(-1)
        self.coefficients = np.asarray(coefficients, dtype=float)
        m = self.durations_s.size
        if m < 1 or self.coefficients.ndim != 3 or self.coefficients.shape[:2] != (m, 4):
            raise ValueError(f'coefficients shape {self.coefficients.shape} must be (segments={m}, 4, degree+1)')
        if not np.all(np.isfinite(self.durations_s)) or np.any(self.durations_s <= 0):
            raise ValueError(f'segment durations must be finite and > 0, got min {self.durations_s.min()}')
        if not np.all(np.isfinite(self.coefficients)):
            raise ValueError('coefficients contain a non-finite value')
        self.breaks_s = np.concatenate([[0.0], np.cumsum(self.durations_s)])

    @property
    def n_segments(self) -> int:
        return self.durations_s.size

    @property
    def degree(self) -> int:
        return self.coefficients.shape[2] - 1

    @property
    def duration_s(self) -> float:
        return float(self.breaks_s[-1])

    # --- evaluation -----------------------------------------------------------------------
    def evaluate_local(self, segment, tau_s, order=0) -> np.ndarray:
        """Derivative `order` of all axes at local times tau_s on segments `segment` (same shape): (..., 4)."""
        seg = np.asarray(segment, dtype=int)
        tau = np.asarray(tau_s, dtype=float)
        seg, tau = np.broadcast_arrays(seg, tau)
        n = self.degree + 1
        if order >= n:
            return np.zeros(tau.shape + (4,))
        c = self.coefficients[:, :, order:] * derivative_factors(n, order)  # (M, 4, n - order)
        cs = c[seg.reshape(-1)]  # (N, 4, n - order)
        t = tau.reshape(-1, 1)
        out = cs[:, :, -1]
        for k in range(cs.shape[2] - 2, -1, -1):  # Horner
            out = out * t + cs[:, :, k]
        return out.reshape(tau.shape + (4,))

    def locate(self, t_s):
        """(segment index, local time) for global times, clamped to [0, duration]."""
        t = np.clip(np.asarray(t_s, dtype=float), 0.0, self.duration_s)
        seg = np.clip(np.searchsorted(self.breaks_s, t, side='right') - 1, 0, self.n_segments - 1)
        return seg, np.minimum(t - self.breaks_s[seg], self.durations_s[seg])

    def evaluate(self, t_s, order=0) -> np.ndarray:
        """Derivative `order` (0 = position) at global times t_s (any shape): (..., 4). Held outside [0, T]."""
        seg, tau = self.locate(t_s)
        return self.evaluate_local(seg, tau, order)

    def segment_grid(self, samples_per_segment: int):
        """(segment index, local time) of `samples_per_segment` evenly spaced samples on each segment, ends included."""
        s = np.linspace(0.0, 1.0, samples_per_segment)
        seg = np.repeat(np.arange(self.n_segments), samples_per_segment)
        return seg, (self.durations_s[:, None] * s[None, :]).reshape(-1)

    # --- summary numbers --------------------------------------------------------------------
    def segment_peaks(self, order: int) -> np.ndarray:
        """Max over each segment of |d^order p/dt^order| (x, y, z norm), from dense samples: (M,)."""
        seg, tau = self.segment_grid(_PEAK_SAMPLES_PER_SEGMENT)
        norm = np.linalg.norm(self.evaluate_local(seg, tau, order)[:, :3], axis=1)
        return norm.reshape(self.n_segments, -1).max(axis=1)

    def max_speed(self) -> float:
        return float(self.segment_peaks(1).max())

    def max_acceleration(self) -> float:
        return float(self.segment_peaks(2).max())

    def max_jerk(self) -> float:
        return float(self.segment_peaks(3).max())

    def segment_lengths(self) -> np.ndarray:
        """Arc length of each segment (composite Gauss-Legendre on the speed): (M,)."""
        tau = self.durations_s[:, None] * _GAUSS_NODES[None, :]
        seg = np.repeat(np.arange(self.n_segments)[:, None], _GAUSS_NODES.size, axis=1)
        speed = np.linalg.norm(self.evaluate_local(seg, tau, 1)[..., :3], axis=-1)
        return self.durations_s * (speed @ _GAUSS_WEIGHTS)

    def arc_length(self) -> float:
        return float(self.segment_lengths().sum())

    # --- outputs ----------------------------------------------------------------------------
    def sample_times(self, rate_hz: float) -> np.ndarray:
        """0, 1/rate, 2/rate, ... and the end time (kept strictly increasing)."""
        if not np.isfinite(rate_hz) or rate_hz <= 0:
            raise ValueError(f'sample rate_hz = {rate_hz!r} must be finite and > 0')
        t = np.arange(0.0, self.duration_s, 1.0 / rate_hz)
        if self.duration_s - t[-1] < 1e-9:
            t = t[:-1]
        return np.append(t, self.duration_s)

    def to_sampled(self, rate_hz: float) -> SampledTrajectory:
        t = self.sample_times(rate_hz)
        return SampledTrajectory(t, self.evaluate(t, 0), self.evaluate(t, 1), self.evaluate(t, 2))

    def to_dict(self) -> dict:
        return {'segments': [{'duration': float(d), 'coefficients': {a: c[k].tolist() for k, a in enumerate(AXES)}}
                             for d, c in zip(self.durations_s, self.coefficients)]}

    @classmethod
    def from_dict(cls, data: dict) -> 'PiecewisePolynomial':
        segments = data['segments']
        return cls([s['duration'] for s in segments],
                   [[s['coefficients'][a] for a in AXES] for s in segments])
