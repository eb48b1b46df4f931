"""The vehicle's state from motion-capture poses alone (position_controller's `state_source: external_pose`).

A motion-capture pose is precise (about 1 mm) and fresh (a few ms), but carries no velocity, and differencing it
amplifies the noise by sqrt(2) / dt: 0.14 m/s RMS at 100 Hz per mm, which kd turns straight into tilt.

Velocity: an alpha-beta filter per axis, the steady-state Kalman filter of a constant-velocity model driven by white
acceleration. Each pose at dt after the last: predict p^ = p + v dt, innovation r = z - p^, then
    p = p^ + alpha r,    v = v + (beta / dt) r,
with the gains from the tracking index lambda = sigma_a dt^2 / sigma_p (sigma_a: the acceleration the vehicle may
do unannounced, sigma_p: the pose's noise):
    s = (4 + lambda - sqrt(8 lambda + lambda^2)) / 4,   alpha = 1 - s^2,   beta = 2 (2 - alpha) - 4 sqrt(1 - alpha).
Why this filter: it follows a constant velocity without lag (a low-pass of differences lags by its time constant
at any velocity), its one knob is physical (noise against acceleration), and it takes the stream's uneven dt and
lost frames (the gains are recomputed from each dt).
A gap longer than max_gap_s (or the first pose) restarts it: position the pose, velocity zero.

Attitude: the pose's. Body rates: the rotation from the last attitude to this one over dt (2 vec(q_last* q) / dt),
smoothed with the same alpha (the controllers here do not use them; a user controller may).
"""

import math

import numpy as np

from quad_common import rotations
from quad_common.types import State


def alpha_beta_gains(dt_s: float, position_noise_m: float, acceleration_mps2: float) -> tuple[float, float]:
    """(alpha, beta) of the steady-state alpha-beta filter at this dt (module docstring)."""
    lam = acceleration_mps2 * dt_s * dt_s / position_noise_m
    s = (4.0 + lam - math.sqrt(8.0 * lam + lam * lam)) / 4.0
    alpha = 1.0 - s * s
    return alpha, 2.0 * (2.0 - alpha) - 4.0 * math.sqrt(1.0 - alpha)


class PoseNotNewer(ValueError):
    """A pose stamped at or before the last one taken (a repeated or reordered frame)."""


class PoseStateFilter:
    """Poses (stamp, ENU position, FLU -> ENU attitude) in, State out (module docstring)."""

    def __init__(self, position_noise_m: float, acceleration_mps2: float, max_gap_s: float):
        for name, value in (('pose_position_noise_m', position_noise_m),
                            ('pose_acceleration_mps2', acceleration_mps2), ('max_gap_s', max_gap_s)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f'{name} = {value!r} must be a finite number > 0')
        self.position_noise_m = position_noise_m
        self.acceleration_mps2 = acceleration_mps2
        self.max_gap_s = max_gap_s
        self.stamp_ns = None
        self.position = self.velocity = self.body_rates = np.zeros(3)
        self.quaternion = np.array([0.0, 0.0, 0.0, 1.0])
        self.restarts = 0

    def update(self, stamp_ns: int, position, quaternion) -> State:
        """The state at stamp_ns. A pose not newer than the last raises PoseNotNewer, one not finite ValueError
        (nothing changes)."""
        z = np.asarray(position, dtype=float)
        q = rotations.normalize(quaternion)
        if z.shape != (3,) or not np.isfinite(z).all():
            raise ValueError(f'pose position {z.tolist()} is not three finite numbers')
        if self.stamp_ns is not None and stamp_ns <= self.stamp_ns:
            raise PoseNotNewer(f'pose stamp {stamp_ns * 1e-9:.6f} s is not after the last {self.stamp_ns * 1e-9:.6f} s')
        dt = None if self.stamp_ns is None else (stamp_ns - self.stamp_ns) * 1e-9
        if dt is None or dt > self.max_gap_s:
            self.restarts += dt is not None
            self.position, self.velocity, self.body_rates = z, np.zeros(3), np.zeros(3)
        else:
            alpha, beta = alpha_beta_gains(dt, self.position_noise_m, self.acceleration_mps2)
            predicted = self.position + self.velocity * dt
            innovation = z - predicted
            self.position = predicted + alpha * innovation
            self.velocity = self.velocity + (beta / dt) * innovation
            dq = rotations.multiply(rotations.conjugate(self.quaternion), q)
            measured_rates = (2.0 if dq[3] >= 0 else -2.0) * dq[:3] / dt
            self.body_rates = self.body_rates + alpha * (measured_rates - self.body_rates)
        self.stamp_ns, self.quaternion = stamp_ns, q
        return State(position=self.position.copy(), velocity=self.velocity.copy(), quaternion=q.copy(),
                     body_rates=self.body_rates.copy())
