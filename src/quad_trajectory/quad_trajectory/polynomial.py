"""Piecewise-polynomial trajectory over the axes (x, y, z, yaw).

Segment i lasts durations_s[i]; on it each axis is sum_k c[i, axis, k] * tau^k with tau the local
time in [0, durations_s[i]] (ascending powers, the plan JSON layout of docs/design.md).
"""

import json

import numpy as np
from numpy.polynomial.legendre import leggauss

from quad_common.sampled_trajectory import SampledTrajectory

AXES = ('x', 'y', 'z', 'yaw')
_PEAK_SAMPLES_PER_SEGMENT = 128
_PEAK_GRID = np.linspace(0.0, 1.0, _PEAK_SAMPLES_PER_SEGMENT)
_CHUNK_SEGMENTS = 2048   # grid evaluations work on this many segments at a time (bounded memory)
# arc length: composite Gauss-Legendre, 16 pieces x 5 nodes per segment (the speed |v| has kinks where v = 0)
_PIECES = 16
_NODES, _WEIGHTS = leggauss(5)
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
        s = seg.reshape(-1)
        t = tau.reshape(-1, 1)
        out = c[s, :, -1]
        for k in range(c.shape[2] - 2, -1, -1):  # Horner, gathering one coefficient at a time: O(N) memory
            out = out * t + c[s, :, k]
        return out.reshape(tau.shape + (4,))

    def grid_values(self, order: int, s, segments=slice(None), axes=4) -> np.ndarray:
        """Derivative `order` at normalised times s in [0, 1] (S,) of every segment in `segments`: (m, axes, S)
        for the first `axes` axes.

        p^(order)(T s) = sum_k f_k c_k T^(k - order) s^(k - order): one matrix product of the per-segment
        coefficients in normalised time with the fixed Vandermonde matrix of s, no per-sample gather."""
        n = self.degree + 1
        T = self.durations_s[segments]
        if order >= n:
            return np.zeros((T.size, axes, np.size(s)))
        k = np.arange(n - order)
        c = self.coefficients[segments][:, :axes, order:] * derivative_factors(n, order) * (T[:, None, None] ** k)
        return c @ (np.asarray(s, dtype=float)[:, None] ** k).T

    def _chunks(self):
        for start in range(0, self.n_segments, _CHUNK_SEGMENTS):
            yield slice(start, min(start + _CHUNK_SEGMENTS, self.n_segments))

    def locate(self, t_s):
        """(segment index, local time) for global times, clamped to [0, duration]."""
        t = np.clip(np.asarray(t_s, dtype=float), 0.0, self.duration_s)
        seg = np.clip(np.searchsorted(self.breaks_s, t, side='right') - 1, 0, self.n_segments - 1)
        return seg, np.minimum(t - self.breaks_s[seg], self.durations_s[seg])

    def evaluate(self, t_s, order=0) -> np.ndarray:
        """Derivative `order` (0 = position) at global times t_s (any shape): (..., 4). Held outside [0, T]."""
        seg, tau = self.locate(t_s)
        return self.evaluate_local(seg, tau, order)

    # --- summary numbers --------------------------------------------------------------------
    def segment_peaks(self, order: int) -> np.ndarray:
        """Max over each segment of |d^order p/dt^order| (x, y, z norm), from 128 evenly spaced samples: (M,)."""
        out = np.empty(self.n_segments)
        for part in self._chunks():
            v = self.grid_values(order, _PEAK_GRID, part, axes=3)
            out[part] = np.sqrt(np.einsum('mas,mas->ms', v, v).max(axis=1))
        return out

    def max_speed(self) -> float:
        return float(self.segment_peaks(1).max())

    def max_acceleration(self) -> float:
        return float(self.segment_peaks(2).max())

    def max_jerk(self) -> float:
        return float(self.segment_peaks(3).max())

    def segment_lengths(self) -> np.ndarray:
        """Arc length of each segment (composite Gauss-Legendre on the speed): (M,)."""
        out = np.empty(self.n_segments)
        for part in self._chunks():
            v = self.grid_values(1, _GAUSS_NODES, part, axes=3)
            out[part] = self.durations_s[part] * (np.sqrt(np.einsum('mas,mas->ms', v, v)) @ _GAUSS_WEIGHTS)
        return out

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

    def segments_json(self) -> str:
        """json.dumps(self.to_dict()['segments']) without a Python object per value: each axis's (M, n)
        coefficients and the durations are encoded in one call by json's C encoder, then cut per segment
        (the rows hold only numbers, so '], [' separates them)."""
        axes = [json.dumps(self.coefficients[:, k].tolist())[2:-2].split('], [') for k in range(len(AXES))]
        durations = json.dumps(self.durations_s.tolist())[1:-1].split(', ')
        names = [json.dumps(a) for a in AXES]
        return '[' + ', '.join('{"duration": ' + d + ', "coefficients": {' + ', '.join(
            f'{n}: [{c}]' for n, c in zip(names, cs)) + '}}' for d, *cs in zip(durations, *axes)) + ']'

    @classmethod
    def from_dict(cls, data: dict) -> 'PiecewisePolynomial':
        segments = data['segments']
        return cls([s['duration'] for s in segments],
                   [[s['coefficients'][a] for a in AXES] for s in segments])
