"""The velocity the controller flies, made consistent with the odometry's own position at low frequencies.

An autopilot's estimate can carry a velocity that is not its position's derivative, wrong at low frequencies
where the position is not (PX4's EKF2: docs/quad_control.md "Velocity from the position"); through kd that error
is a slow force pushing the vehicle off its plan. The blend keeps the odometry's velocity above 1 / (2 pi tau) and
the position's derivative below it (a complementary filter):

    c_k = c_k-1 + dt / (tau + dt) * ((p_k - p_k-1) / dt - (v_k + v_k-1) / 2 - c_k-1),    v_flown = v_k + c_k

The difference quotient is set against the mean velocity over the same interval (the trapezoid), so an estimate
whose velocity is its position's derivative gives c = O(dt^2) and the blend adds no lag to the loop. tau = 0 flies
the odometry's velocity unchanged (c is cleared).
"""

from dataclasses import replace

import numpy as np

from quad_common.types import State


class VelocityBlend:
    def __init__(self):
        self.previous = None                  # (stamp_ns, position, velocity) of the newest odometry
        self.correction_mps = np.zeros(3)     # c: the position's derivative minus the odometry's velocity, filtered

    def __call__(self, stamp_ns: int, state: State, time_constant_s: float) -> State:
        """The state with its velocity blended at tau = time_constant_s (>= 0); an odometry not newer than the
        previous one leaves c as it is."""
        if not time_constant_s:   # off: nothing kept, nothing computed on the odometry's path
            if self.previous is not None:   # c is non-zero only once an odometry was kept
                self.previous, self.correction_mps = None, np.zeros(3)
            return state
        position, velocity = np.asarray(state.position, dtype=float), np.asarray(state.velocity, dtype=float)
        if self.previous is None or stamp_ns > self.previous[0]:
            if self.previous is not None:
                dt_s = (stamp_ns - self.previous[0]) * 1e-9
                derivative = (position - self.previous[1]) / dt_s
                self.correction_mps = self.correction_mps + dt_s / (time_constant_s + dt_s) * (
                    derivative - 0.5 * (velocity + self.previous[2]) - self.correction_mps)
            self.previous = (stamp_ns, position.copy(), velocity.copy())
        return replace(state, velocity=velocity + self.correction_mps)
