"""The autopilot's attitude response in front of quad_sim's fast inner loop, and the telemetry delay line.

Both autopilots shape the attitude target before their attitude P + rate PID: ArduPilot's input shaping with
ATC_INPUT_TC (libraries/AC_AttitudeControl/AC_AttitudeControl.cpp, input_quaternion -> attitude_command_model),
PX4's angle P MC_ROLL_P (src/modules/mc_att_control/AttitudeControl). Here that is a first-order response on
SO(3): the commanded attitude q_c moves toward the target q_t with angular velocity

    w = log(q_c^-1 q_t) / tau + w_ff        (body frame, rad/s)

which the autopilot's own attitude loop then tracks (`emulated_vehicle`): quad_sim's so3_pd cascade, an angle P
on the quaternion error feeding a body-rate P (PX4's mc_att_control and ArduPilot's AC_AttitudeControl both
work on the quaternion error, so a large yaw error never turns the tilt the wrong way, as the seed's eq. 6 on
Euler-angle differences does: from a 180 deg yaw error and a 0.3 m offset eq. 6 runs away). Its gains are
PX4's defaults MC_ROLL_P = MC_PITCH_P = 6.5, MC_YAW_P = 2.8 with 60 / 30 rad/s rate loops, without roll/pitch
rate feed-forward, so its own lag is 1 / MC_ROLL_P = 0.154 s. The default total lag is 0.19 s, inside the
0.17-0.21 s measured on ArduCopter SITL (issue 13; test_attitude_response.py): calibrated to that measurement,
not taken from ATC_INPUT_TC.

A requested total lag L (the mean delay -G'(0)/G(0) of the attitude response G, what an FOPDT fit calls
tau + dead time, `quadflight identify`'s lag) is reached by `tau_for_lag_s`: mean delays of systems in
series add, and the emulated loop ignores the roll/pitch rate feed-forward, so

    L = tau + lag_loop,   lag_loop = quad_sim.attitude_poles.attitude_mean_delay_s(vehicle)  (1 / angle_p: 0.154 s)

(the default: tau = 0.19 - 0.154 = 0.036 s).
"""

import collections
import math

import numpy as np

from quad_common import rotations
from quad_common.vehicle import load_vehicle
from quad_sim.attitude_poles import attitude_mean_delay_s

DEFAULT_LAG_S = 0.19     # total roll/pitch lag: ArduCopter SITL's 0.17-0.21 s (issue 13)
# the autopilot's attitude loop in place of a vehicle file's eq. 6: PX4's defaults (mc_att_control_params.c
# MC_ROLL_P / MC_PITCH_P 6.5, MC_YAW_P 2.8; rate loops as config/plant_family.yaml's autopilot_so3)
AUTOPILOT_LOOP = {'type': 'so3_pd', 'angle_p': [6.5, 6.5, 2.8], 'rate_p': [60.0, 60.0, 30.0],
                  'use_feedforward_rates': False}


def emulated_vehicle(vehicle_path, plant: dict | None = None):
    """The vehicle file as the emulator flies it: a file whose onboard loop is the seed's eq. 6 gets the
    autopilot's quaternion loop (AUTOPILOT_LOOP); one that already names an autopilot-like loop (so3_pd, lag)
    keeps it. `plant`: further plant-only fields (thrust_error, mass_error)."""
    given = load_vehicle(vehicle_path)
    swap = {'attitude_loop': AUTOPILOT_LOOP} if given.attitude_loop.type == 'eq6' else {}
    overrides = {**swap, **(plant or {})}
    return load_vehicle(vehicle_path, plant=overrides) if overrides else given


def default_tau_s(vehicle) -> float:
    """Shaping for the default total lag on an emulated vehicle (emulated_vehicle) whose loop is the autopilot's;
    0 for a vehicle file that brings its own autopilot-like loop (it already is the response wanted)."""
    return tau_for_lag_s(vehicle, DEFAULT_LAG_S) if vehicle.attitude_loop.type == 'so3_pd' and \
        not vehicle.attitude_loop.use_feedforward_rates else 0.0


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
    return max(attitude_mean_delay_s(vehicle, 0), attitude_mean_delay_s(vehicle, 1))


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
        """(sample time, value) of the newest sample not younger than delay_s; None while none is that old (a
        fresh vehicle does not send its first samples early: the telemetry is delay_s old from the first)."""
        while len(self._samples) > 1 and self._samples[1][0] <= now_s - self.delay_s:
            self._samples.popleft()
        if not self._samples or self._samples[0][0] > now_s - self.delay_s:
            return None
        return self._samples[0]
