"""A trajectory known only at dense samples, evaluated by quintic Hermite interpolation.

This is how a consumer reads the `trajectory` topic (docs/design.md, docs/interfaces.md): each interval
[t_k, t_k+1] is the unique quintic matching position, velocity and acceleration at both ends,
so position is C2 across samples and jerk is available between them. Axes are (x, y, z, yaw);
yaw is stored unwrapped.
"""

import bisect

import numpy as np

from quad_common.types import Reference


def _quintic_coefficients(h, p0, v0, a0, p1, v1, a1):
    """Coefficients c0..c5 in normalised time s = (t - t0) / h, s in [0, 1]."""
    dp = p1 - p0
    hv0, hv1 = v0 * h, v1 * h
    ha0, ha1 = a0 * h * h, a1 * h * h
    return np.stack([
        p0,
        hv0,
        ha0 / 2,
        10 * dp - 6 * hv0 - 4 * hv1 - (3 * ha0 - ha1) / 2,
        -15 * dp + 8 * hv0 + 7 * hv1 + (3 * ha0 - 2 * ha1) / 2,
        6 * dp - 3 * hv0 - 3 * hv1 - (ha0 - ha1) / 2,
    ], axis=-1)


def hermite_segment_coefficients(h, p0, v0, a0, p1, v1, a1):
    """The same quintic in seconds: coefficients of (t - t0)^0..5 (h broadcast against the values)."""
    return _quintic_coefficients(h, p0, v0, a0, p1, v1, a1) / np.asarray(h)[..., None] ** np.arange(6)


# d-th derivative of sum_m c_m s^m is sum_{m >= d} c_m m! / (m - d)! s^(m - d): factors and powers per (d, m)
_ORDERS, _TERMS = np.arange(4)[:, None], np.arange(6)[None, :]
_FACTORS = np.array([[float(np.prod(np.arange(m - d + 1, m + 1))) if m >= d else 0.0 for m in range(6)]
                     for d in range(4)])
_POWERS = np.maximum(_TERMS - _ORDERS, 0)
_ORDER_POWERS = np.arange(4)[:, None]   # h^d per derivative d


class SampledTrajectory:
    """Samples t (N,), and per axis (x, y, z, yaw) position, velocity, acceleration (N, 4)."""

    def __init__(self, times_s, position, velocity, acceleration):
        t = np.asarray(times_s, dtype=float)
        p, v, a = (np.asarray(x, dtype=float).reshape(len(t), 4) for x in (position, velocity, acceleration))
        if len(t) < 1:
            raise ValueError('trajectory has no points')
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(p)) and np.all(np.isfinite(v))
                and np.all(np.isfinite(a))):
            raise ValueError('trajectory contains a non-finite sample')
        if len(t) > 1 and np.any(np.diff(t) <= 0):
            k = int(np.argmax(np.diff(t) <= 0))
            raise ValueError(f'trajectory time_from_start must increase: sample {k + 1} at {t[k + 1]} s '
                             f'follows {t[k]} s')
        p = p.copy()
        p[:, 3] = np.unwrap(p[:, 3])
        self.times_s, self.position, self.velocity, self.acceleration = t, p, v, a
        self._times = t.tolist()   # reference()'s search: bisect on floats, no numpy call
        if len(t) > 1:
            h = np.diff(t)[:, None]
            self._coef = _quintic_coefficients(h, p[:-1], v[:-1], a[:-1], p[1:], v[1:], a[1:])  # (N-1, 4, 6)

    @property
    def duration_s(self) -> float:
        return float(self.times_s[-1] - self.times_s[0])

    def evaluate(self, t_s, order=3):
        """Derivatives 0..order at times t_s (any shape): array (order+1, *t.shape, 4).

        Outside [t_0, t_end] the first/last sample is held with zero derivatives.
        """
        t = np.asarray(t_s, dtype=float)
        flat = t.reshape(-1)
        out = np.zeros((order + 1, flat.size, 4))
        before = flat <= self.times_s[0]
        after = flat >= self.times_s[-1]
        out[0, before] = self.position[0]
        out[0, after] = self.position[-1]
        inside = ~(before | after)
        if np.any(inside):
            k = np.clip(np.searchsorted(self.times_s, flat[inside], side='right') - 1, 0, len(self.times_s) - 2)
            h = self.times_s[k + 1] - self.times_s[k]
            s = (flat[inside] - self.times_s[k]) / h
            c = self._coef[k]  # (n, 4, 6)
            for d in range(order + 1):
                if d > 5:
                    break
                powers = np.arange(6 - d)
                factor = np.array([np.prod(np.arange(i + 1, i + d + 1)) for i in powers], dtype=float)
                poly = np.einsum('naj,nj->na', c[:, :, d:], factor * s[:, None] ** powers)
                out[d, inside] = poly / h[:, None] ** d
        return out.reshape((order + 1,) + t.shape + (4,))

    def reference(self, t_s) -> Reference:
        """The flat-output reference at one time (evaluate(t, 3) for a single t, without its array set-up:
        the controller calls this every tick)."""
        t, times = float(t_s), self._times
        if t <= times[0] or t >= times[-1]:
            derivatives = np.zeros((4, 4))
            derivatives[0] = self.position[0] if t <= times[0] else self.position[-1]
        else:
            k = min(max(bisect.bisect_right(times, t) - 1, 0), len(times) - 2)   # np.searchsorted(side='right')
            h = times[k + 1] - times[k]
            s = (t - times[k]) / h
            derivatives = (_FACTORS * s ** _POWERS) @ self._coef[k].T / h ** _ORDER_POWERS
        p, v, a, j = derivatives   # rows of a fresh array: the Reference's vectors share nothing with the samples
        return Reference(position=p[:3], velocity=v[:3], acceleration=a[:3], jerk=j[:3], yaw=float(p[3]),
                         yaw_rate=float(v[3]))
