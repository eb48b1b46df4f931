"""Online estimate of the vehicle's linear air drag D (1/s, horizontal), for the plan's drag feed-forward D v_T.

Horizontally the vehicle obeys v' = u - D v + b, with u = f b3 (the commanded specific force along the estimate's
body z, horizontal part) and b a slow external acceleration (wind, a tilt or thrust bias). Both sides through the
same first-order filter H = 1 / (T_f s + 1) give, without differentiating the velocity,

    y = (v - H v) / T_f - H u = -D phi + H b,    phi = H v

x and y share D, each axis has its own bias. D is the least-squares fit over exponentially forgotten sums
(S <- exp(-w dt / T) S + w dt s for s in 1, phi, y, phi^2, phi y; T the forgetting time), the biases eliminated:

    D = -sum_i cov(phi_i, y_i) / sum_i var(phi_i),  clamped to [0, MAX_PER_S]

Each sample's weight w = min(1, |H v_T|^2 / EXCITED_MPS^2) comes from the plan's own speed (independent of the
estimate's noise): while the plan holds a point nothing is learnt and nothing forgotten, so a hover, where the
velocity is noise alone, cannot pull D anywhere. The sums start from the prior D0 (drag_feedforward_per_s) as if
PRIOR_S had been flown at EXCITED_MPS (a few tenths of a second of a leg outweigh it), and the first
WARMUP_TIME_CONSTANTS T_f after a (re)start are not learnt from (the filters start at the current values). The
velocity noise enters phi too and biases D toward 0 by var(noise) / var(phi): a few % at the blended velocity's
0.1 m/s against a plan at 0.8 m/s.
"""

import numpy as np

FILTER_TIME_CONSTANT_S = 0.3   # T_f: smooths the velocity's noise, far shorter than a leg (0.1-2 s all work)
EXCITED_MPS = 0.3              # plan speeds below this are weighted down (squared): their drag is below the noise
MAX_PER_S = 3.0                # the estimate's range [0, MAX_PER_S] (1/s)
PRIOR_S = 1.0                  # the prior D0 weighs as this many s of flight at EXCITED_MPS
ABSURD = 1e3                   # a sample beyond this (m/s, m/s^2) is no flight (an estimate's glitch): left out
WARMUP_TIME_CONSTANTS = 1.0    # after a (re)start the filters settle for this many T_f before D is learnt


class DragEstimate:
    def __init__(self, prior_per_s: float, learning_time_s: float,
                 filter_time_constant_s: float = FILTER_TIME_CONSTANT_S):
        if not (np.isfinite(learning_time_s) and learning_time_s > 0.0):
            raise ValueError(f'learning_time_s = {learning_time_s!r} must be a number > 0')
        self.learning_time_s = float(learning_time_s)
        self.filter_time_constant_s = float(filter_time_constant_s)
        self.drag_per_s = float(np.clip(prior_per_s, 0.0, MAX_PER_S))
        # exponentially weighted sums (weight in s), per horizontal axis: 1, phi, y, phi^2, phi y; the prior as
        # PRIOR_S of flight at EXCITED_MPS with the drag D0
        self.sum_1 = np.full(2, PRIOR_S)
        self.sum_phi = np.zeros(2)
        self.sum_y = np.zeros(2)
        self.sum_phi2 = np.full(2, PRIOR_S * EXCITED_MPS ** 2 / 2.0)
        self.sum_phi_y = -self.drag_per_s * self.sum_phi2
        self.restart()

    def restart(self):
        """Filters restarted at the next sample (the commands before it may not have been flown); D is kept."""
        self.filtered = None    # (H v, H u, H v_T) of the horizontal axes
        self.settling_s = 0.0

    def update(self, velocity, force_mps2, ref_velocity, dt_s: float) -> float:
        """One sample: the vehicle's velocity, the specific force acting on it over the last step (f b3, world
        frame) and the plan's velocity (each 3 or 2 long; x, y are used), dt_s since the previous sample; returns D."""
        v = np.asarray(velocity, dtype=float)[:2]
        u = np.asarray(force_mps2, dtype=float)[:2]
        v_t = np.asarray(ref_velocity, dtype=float)[:2]
        if not (np.isfinite(v).all() and np.isfinite(u).all() and np.isfinite(v_t).all() and np.isfinite(dt_s)):
            return self.drag_per_s
        if max(np.abs(v).max(), np.abs(u).max(), np.abs(v_t).max()) > ABSURD:   # no flight: the filters restart
            self.restart()
            return self.drag_per_s
        if self.filtered is None:
            self.filtered = (v.copy(), u.copy(), v_t.copy())
            return self.drag_per_s
        if dt_s <= 0.0:
            return self.drag_per_s
        t_f = self.filter_time_constant_s
        a = dt_s / (t_f + dt_s)
        hv, hu, hvt = (old + a * (new - old) for old, new in zip(self.filtered, (v, u, v_t)))
        self.filtered = (hv, hu, hvt)
        self.settling_s += dt_s
        if self.settling_s < WARMUP_TIME_CONSTANTS * t_f:
            return self.drag_per_s
        y = (v - hv) / t_f - hu
        weight = min(1.0, float(hvt @ hvt) / EXCITED_MPS ** 2)
        if weight <= 0.0:
            return self.drag_per_s
        keep, w = np.exp(-weight * dt_s / self.learning_time_s), weight * dt_s
        self.sum_1 = keep * self.sum_1 + w
        self.sum_phi = keep * self.sum_phi + w * hv
        self.sum_y = keep * self.sum_y + w * y
        self.sum_phi2 = keep * self.sum_phi2 + w * hv * hv
        self.sum_phi_y = keep * self.sum_phi_y + w * hv * y
        variance = float(np.sum(self.sum_phi2 - self.sum_phi ** 2 / self.sum_1))
        covariance = float(np.sum(self.sum_phi_y - self.sum_phi * self.sum_y / self.sum_1))
        if variance > 1e-9 and np.isfinite(covariance):
            self.drag_per_s = float(np.clip(-covariance / variance, 0.0, MAX_PER_S))
        return self.drag_per_s
