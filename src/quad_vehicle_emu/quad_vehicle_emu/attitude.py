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
0.17-0.21 s measured on ArduCopter SITL (test_attitude_response.py): calibrated to that measurement,
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

DEFAULT_LAG_S = 0.19     # total roll/pitch lag: ArduCopter SITL's 0.17-0.21 s
# the autopilot's attitude loop in place of a vehicle file's eq. 6: PX4's defaults (mc_att_control_params.c
# MC_ROLL_P / MC_PITCH_P 6.5, MC_YAW_P 2.8; rate loops as config/plant_family.yaml's autopilot_so3)
AUTOPILOT_LOOP = {'type': 'so3_pd', 'angle_p': [6.5, 6.5, 2.8], 'rate_p': [60.0, 60.0, 30.0],
                  'use_feedforward_rates': False}

# PX4 v1.16 SIH's own roll/pitch rate loop (sihsim_quadx), from PX4's source defaults, no measured figure:
# - mc_rate_control (RateControl.cpp): torque = MC_ROLLRATE_K (P e + I int(e) - D d(rate)/dt), the D term on
#   the measured rate's derivative; mc_rate_control_params.c: P 0.15, I 0.2, D 0.003, K 1 (pitch the same).
# - control allocation (ControlAllocationPseudoInverse::updateControlAllocationMatrixScale, normalize_rpy for
#   multicopters): the mix's roll and pitch columns scaled to an RMS of 1 / sqrt(n / 2): +-1/sqrt(2) per motor
#   of the quad X (10040_sihsim_quadx: CA_ROTOR_COUNT 4 at (+-1, +-1)).
# - sih.cpp (generate_force_and_torques): roll torque = SIH_L_ROLL SIH_T_MAX (-u0 + u1 + u2 - u3), motors a
#   first order of SIH_T_TAU (read_motors); sih_params.yaml: SIH_L_ROLL = SIH_L_PITCH 0.2 m, SIH_T_MAX 5 N,
#   SIH_IXX = SIH_IYY 0.025 kg m^2, SIH_T_TAU 0.05 s.
# So one unit of normalised torque is 0.2 * 5 * 4 / sqrt(2) = 2.83 N m, g = 113 rad/s^2 on 0.025 kg m^2, and
# the rate loop w' = g (P e - D w') has the bandwidth g P / (1 + g D) = 12.7 rad/s (the emulated autopilot's
# default: 60), behind SIH's 0.05 s motors (px4_quad.yaml: 0.03 s). Left out: the I term (0.2 against P 0.15: a
# slow trim), the D term's IMU_DGYRO_CUTOFF filter, MC_ROLLRATE_MAX (220 deg/s, not reached on the square), SIH's
# angular damper SIH_KDW (1 /s on 0.025 kg m^2, against 12.7); yaw keeps the default loop. The angle loop is
# unchanged (MC_ROLL_P 6.5), so its mean delay stays 1 / 6.5 (the rate loop adds none) and --attitude-tau-s
# keeps its meaning.
SIH_TORQUE_PER_UNIT_NM = 0.2 * 5.0 * 4.0 / math.sqrt(2.0)   # SIH_L_ROLL SIH_T_MAX 4 / sqrt(2)
SIH_RATE_GAIN_RADPS2 = SIH_TORQUE_PER_UNIT_NM / 0.025      # / SIH_IXX
MC_ROLLRATE_P, MC_ROLLRATE_D = 0.15, 0.003
PX4_SIH_RATE_BANDWIDTH_RADPS = SIH_RATE_GAIN_RADPS2 * MC_ROLLRATE_P / (1.0 + SIH_RATE_GAIN_RADPS2 * MC_ROLLRATE_D)
SIH_T_TAU_S = 0.05
RATE_LOOPS = {
    'default': {'attitude_loop': AUTOPILOT_LOOP},
    'px4-sih': {'attitude_loop': {**AUTOPILOT_LOOP, 'rate_p': [PX4_SIH_RATE_BANDWIDTH_RADPS,
                                                               PX4_SIH_RATE_BANDWIDTH_RADPS, 30.0]},
                'motor_time_constant_s': SIH_T_TAU_S},
}


def emulated_vehicle(vehicle_path, plant: dict | None = None, rate_loop: str = 'default'):
    """The vehicle file as the emulator flies it: a file whose onboard loop is the seed's eq. 6 gets the
    autopilot's quaternion loop (AUTOPILOT_LOOP; rate_loop 'px4-sih': PX4 SIH's rate loop and motors, above);
    one that already names an autopilot-like loop (so3_pd, lag) keeps it. `plant`: further plant-only fields
    (thrust_error, mass_error)."""
    if rate_loop not in RATE_LOOPS:
        raise ValueError(f'--rate-loop = {rate_loop!r} must be one of {", ".join(RATE_LOOPS)}')
    given = load_vehicle(vehicle_path)
    swap = RATE_LOOPS[rate_loop] if given.attitude_loop.type == 'eq6' else {}
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
    """First-order attitude command model (time constant tau_s; tau_s = 0: the target passes through) behind a
    pure dead time (dead_time_s: the target and its rates are acted on that late; PX4 v1.16 SIH's setpoint ->
    attitude fits 0.09-0.11 s of it before its first order, where a lag of the same mean delay without it keeps a
    stiff position loop stable that PX4 SIH drove into a limit cycle)."""

    def __init__(self, tau_s: float, initial_quaternion, dead_time_s: float = 0.0):
        if not (math.isfinite(tau_s) and tau_s >= 0.0):
            raise ValueError(f'attitude time constant = {tau_s!r} s must be a finite number >= 0')
        if not (math.isfinite(dead_time_s) and 0.0 <= dead_time_s <= 1.0):
            raise ValueError(f'--attitude-dead-time-s = {dead_time_s!r} must be a number in [0, 1]')
        self.tau_s = float(tau_s)
        self.q = rotations.normalize(np.asarray(initial_quaternion, dtype=float))
        self.dead_time_s = float(dead_time_s)
        self._late = collections.deque()   # (time s, target, rates) waiting out the dead time
        self._now_s = 0.0

    def reset(self, quaternion):
        self.q = rotations.normalize(np.asarray(quaternion, dtype=float))
        self._late.clear()

    def _delayed(self, q_target, dt_s: float, rates_ff):
        """The target and rates given dead_time_s ago (the newest at least that old; the current attitude held,
        no rates, until one is)."""
        self._now_s += max(dt_s, 0.0)
        self._late.append((self._now_s, q_target, rates_ff))
        while len(self._late) > 1 and self._late[1][0] <= self._now_s - self.dead_time_s + 1e-9:
            self._late.popleft()
        if self._late[0][0] > self._now_s - self.dead_time_s + 1e-9:
            return self.q, None
        return self._late[0][1], self._late[0][2]

    def step(self, q_target, dt_s: float, rates_ff=None) -> tuple[np.ndarray, np.ndarray]:
        """(commanded quaternion, commanded body rates) after dt_s toward q_target (as it was dead_time_s ago)."""
        if self.dead_time_s:
            q_target, rates_ff = self._delayed(q_target, dt_s, rates_ff)
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
