"""The autopilot's state estimate, as PX4 v1.16 SIH showed it (issue 28): not the truth but the truth's
position and velocity lag_s late, the position off by a slow wander. Its own position hold and its telemetry use
the estimate, so what a position controller flies is the estimate, and the truth wanders with it.

Wander: per axis a first-order Gauss-Markov process (correlation time tau_s, standard deviation wander_m
horizontally, wander_z_m vertically), w' = -w / tau + sqrt(2 sigma^2 / tau) n(t), stepped exactly:
w(t + dt) = a w(t) + sigma sqrt(1 - a^2) n,  a = exp(-dt / tau). PX4 SIH: 0.4-0.8 m RMS off the truth (height
0.3-1.3 m), wandering about 0.5 m a minute, 0.15 s behind. The wander starts at 0 (the estimator initialised
where the vehicle stands). Defaults (lag 0, no wander): the estimate is the truth.
"""

import collections
import math

import numpy as np

from quad_common.types import State


class Estimate:
    def __init__(self, lag_s: float = 0.0, wander_m: float = 0.0, wander_z_m: float = 0.0, tau_s: float = 60.0,
                 seed: int = 0):
        for name, value in (('--estimator-lag-s', lag_s), ('--estimator-wander-m', wander_m),
                            ('--estimator-wander-z-m', wander_z_m)):
            if not (math.isfinite(value) and 0.0 <= value <= 10.0):
                raise ValueError(f'{name} = {value!r} must be a number in [0, 10]')
        if not (math.isfinite(tau_s) and tau_s > 0.0):
            raise ValueError(f'--estimator-wander-tau-s = {tau_s!r} must be a number > 0')
        self.lag_s, self.tau_s = float(lag_s), float(tau_s)
        self.sigma = np.array([wander_m, wander_m, wander_z_m], dtype=float)
        self.rng = np.random.default_rng(seed)
        self.wander = np.zeros(3)   # initialised where the vehicle stands, wandering from there
        self.last_s = None
        self._history = collections.deque()   # (time s, position, velocity) of the truth

    def step(self, now_s: float, truth: State) -> State:
        """The estimate at now_s, given the truth now (call once per loop tick, times increasing)."""
        if self.last_s is not None and self.sigma.any():
            a = math.exp(-max(now_s - self.last_s, 0.0) / self.tau_s)
            self.wander = a * self.wander + self.sigma * math.sqrt(1.0 - a * a) * self.rng.standard_normal(3)
        self.last_s = now_s
        self._history.append((now_s, truth.position.copy(), truth.velocity.copy()))
        while len(self._history) > 1 and self._history[1][0] <= now_s - self.lag_s:
            self._history.popleft()
        _, position, velocity = self._history[0]
        if not self.lag_s and not self.sigma.any():
            return truth
        return State(position=position + self.wander, velocity=velocity, quaternion=truth.quaternion,
                     body_rates=truth.body_rates)
