"""The three values that cross package boundaries, as plain numpy dataclasses.

Frames (docs/design.md, docs/interfaces.md): world `map` ENU, body `base_link` FLU, SI units, quaternions (x, y, z, w).
"""

import math
from dataclasses import dataclass, field

import numpy as np

GRAVITY_MPS2 = 9.81


def _vec(n):
    return field(default_factory=lambda: np.zeros(n))


def all_finite(vectors) -> bool:
    """Whether every value of the vectors is finite: a non-finite value makes their sum inf or nan, and a finite
    sum means none is; only a sum that overflows (or a non-finite value) takes numpy's elementwise check."""
    total = 0.0
    for values in vectors:
        total += sum(values.tolist() if isinstance(values, np.ndarray) else values)
    return math.isfinite(total) or bool(np.isfinite(np.concatenate(vectors)).all())


@dataclass
class State:
    """Vehicle state: world position/velocity, attitude body->world, body rates (FLU)."""

    position: np.ndarray = _vec(3)
    velocity: np.ndarray = _vec(3)
    quaternion: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 0.0, 1.0]))
    body_rates: np.ndarray = _vec(3)

    def is_finite(self) -> bool:
        """Every odometry message is checked: the sum of the values as floats (a few us less than numpy on
        13 values), numpy only when that sum is not finite (a non-finite value, or finite ones that overflow)."""
        return all_finite((self.position, self.velocity, self.quaternion, self.body_rates))


@dataclass
class Reference:
    """Flat-output reference at one instant: position and its derivatives, yaw and its rate."""

    position: np.ndarray = _vec(3)
    velocity: np.ndarray = _vec(3)
    acceleration: np.ndarray = _vec(3)
    jerk: np.ndarray = _vec(3)
    yaw: float = 0.0
    yaw_rate: float = 0.0

    def is_finite(self) -> bool:
        return all(np.all(np.isfinite(v)) for v in
                   (self.position, self.velocity, self.acceleration, self.jerk,
                    self.yaw, self.yaw_rate))


@dataclass
class AttitudeSetpoint:
    """What the position loop hands to the vehicle's attitude loop (the `cmd/attitude_thrust` content).

    specific_force_mps2 is collective thrust / mass along body z (what an ideal accelerometer reads);
    thrust_n = specific_force_mps2 * mass. body_rates is None when no feed-forward is given.
    """

    quaternion: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 0.0, 1.0]))
    specific_force_mps2: float = GRAVITY_MPS2
    body_rates: np.ndarray | None = None

    def is_finite(self) -> bool:
        """The simulator checks every setpoint (State.is_finite's way)."""
        vals = [self.quaternion, [self.specific_force_mps2]]
        if self.body_rates is not None:
            vals.append(self.body_rates)
        return all_finite(vals)
