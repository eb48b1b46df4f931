"""The autopilot's attitude response in front of quad_sim's fast inner loop, and the telemetry delay line.

Both autopilots shape the attitude target before their attitude P + rate PID: ArduPilot's input shaping with
ATC_INPUT_TC (libraries/AC_AttitudeControl/AC_AttitudeControl.cpp, input_quaternion -> attitude_command_model),
PX4's angle P MC_ROLL_P (src/modules/mc_att_control/AttitudeControl). Here that is a first-order response on
SO(3): the commanded attitude q_c moves toward the target q_t with angular velocity

    w = log(q_c^-1 q_t) / tau + w_ff        (body frame, rad/s)

which quad_sim's attitude loop (the seed's eq. 6 with the vehicle YAML's kp/kd) then tracks with w as its rate
feed-forward. With config/vehicles/px4_quad.yaml the bare loop reaches 63 % of a 10 deg roll step in 0.09 s;
tau = 0.08 s in front of it makes that 0.19 s, inside the 0.17-0.21 s measured on ArduCopter SITL (issue 13;
test_attitude_response.py). tau is calibrated to that measurement, not taken from ATC_INPUT_TC or MC_ROLL_P.

A requested total lag L (the mean delay -G'(0)/G(0) of the attitude response G, what an FOPDT fit calls
tau + dead time, `quadflight identify`'s lag) is reached by `tau_for_lag_s`: mean delays of systems in
series add, and the emulator's eq. 6 loop ignores the roll/pitch rate feed-forward, so

    L = tau + lag_loop,   lag_loop = quad_sim.stability.attitude_lag_s(vehicle)  (kd / kp: 0.1 s for px4_quad)

(tau 0.08 -> L = 0.18 s, whose 63 % step rise is the 0.19 s above).
"""

import collections
import math

import numpy as np

from quad_common import rotations
from quad_sim.stability import attitude_lag_s


def _log_body(q_from, q_to) -> np.ndarray:
    """Rotation vector of q_from^-1 q_to (the body-frame rotation from q_from to q_to), shortest way."""
    dq = rotations.multiply(rotations.conjugate(q_from), q_to)
    if dq[3] < 0:
        dq = -dq
    s = math.sqrt(dq[0] ** 2 + dq[1] ** 2 + dq[2] ** 2)
    if s < 1e-12:
        return np.zeros(3)
    return dq[:3] * (2.0 * math.atan2(s, dq[3]) / s)


def _exp_body(q, rotvec) -> np.ndarray:
    angle = float(np.linalg.norm(rotvec))
    if angle < 1e-12:
        return q
    axis = rotvec / angle
    dq = np.array([*(axis * math.sin(angle / 2.0)), math.cos(angle / 2.0)])
    return rotations.normalize(rotations.multiply(q, dq))


def own_lag_s(vehicle) -> float:
    """The roll/pitch lag of the vehicle's onboard loop without shaping (the slower axis)."""
    return max(attitude_lag_s(vehicle, 0), attitude_lag_s(vehicle, 1))


def tau_for_lag_s(vehicle, lag_s: float) -> float:
    """The shaping time constant that makes the vehicle's total roll/pitch lag lag_s (see the module): lag_s minus
    the onboard loop's own mean delay; refused when the loop alone is slower."""
    own_s = own_lag_s(vehicle)
    if not (math.isfinite(lag_s) and lag_s >= own_s):
        raise ValueError(f'attitude lag = {lag_s!r} s: this vehicle\'s own attitude loop already lags {own_s:.3f} s; '
                         f'ask for at least that')
    return float(lag_s - own_s)


class AttitudeResponse:
    """First-order attitude command model (time constant tau_s; tau_s = 0: the target passes through)."""

    def __init__(self, tau_s: float, initial_quaternion):
        if not (math.isfinite(tau_s) and tau_s >= 0.0):
            raise ValueError(f'attitude time constant = {tau_s!r} s must be a finite number >= 0')
        self.tau_s = float(tau_s)
        self.q = rotations.normalize(np.asarray(initial_quaternion, dtype=float))

    def reset(self, quaternion):
        self.q = rotations.normalize(np.asarray(quaternion, dtype=float))

    def step(self, q_target, dt_s: float, rates_ff=None) -> tuple[np.ndarray, np.ndarray]:
        """(commanded quaternion, commanded body rates) after dt_s toward q_target."""
        q_target = rotations.normalize(np.asarray(q_target, dtype=float))
        ff = np.zeros(3) if rates_ff is None else np.asarray(rates_ff, dtype=float)
        if self.tau_s == 0.0 or dt_s <= 0.0:
            self.q = q_target
            return self.q, ff
        err = _log_body(self.q, q_target)
        # exact for the first-order error decay over dt (the error shrinks by exp(-dt/tau))
        moved = err * (1.0 - math.exp(-dt_s / self.tau_s)) + ff * dt_s
        self.q = _exp_body(self.q, moved)
        return self.q, err / self.tau_s + ff


class DelayLine:
    """Samples (time_s, value) read back as they were delay_s ago (telemetry latency)."""

    def __init__(self, delay_s: float):
        if not (math.isfinite(delay_s) and delay_s >= 0.0):
            raise ValueError(f'telemetry latency = {delay_s!r} s must be a finite number >= 0')
        self.delay_s = float(delay_s)
        self._samples = collections.deque()

    def push(self, time_s: float, value):
        self._samples.append((time_s, value))

    def read(self, now_s: float):
        """(sample time, value) of the newest sample not younger than delay_s; None before the first."""
        while len(self._samples) > 1 and self._samples[1][0] <= now_s - self.delay_s:
            self._samples.popleft()
        return self._samples[0] if self._samples else None
