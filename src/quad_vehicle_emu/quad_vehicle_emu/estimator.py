"""The autopilot's state estimate, as PX4 v1.16 SIH showed it: not the truth but the truth's
position lag_s late and off by a slow wander. Its own position hold and its telemetry use the estimate, so what a
position controller flies is the estimate, and the truth wanders with it.

Velocity, attitude and body rates are the truth's now: EKF2's output predictor integrates the IMU at the current
time and publishes them together (what the 0.15 s measured on PX4 SIH trails is the position). Lagging the
velocity too (as this module did at first) contradicts the flights on PX4 SIH: there control_se3 tracked the
square best (0.26-0.27 m), while behind a velocity 0.15 s old, or even 0.05 s, with a current attitude its
disturbance observer (velocity change against the thrust along the attitude now) and kd 11 diverge on every seed
of the emulated flight; the seed pd oscillated at 0.85-0.99 m.

Wander: per axis a first-order Gauss-Markov process (correlation time tau_s, standard deviation wander_m
horizontally, wander_z_m vertically), w' = -w / tau + sqrt(2 sigma^2 / tau) n(t), stepped exactly:
w(t + dt) = a w(t) + sigma sqrt(1 - a^2) n,  a = exp(-dt / tau). PX4 SIH: 0.4-0.8 m RMS off the truth (height
0.3-1.3 m), wandering about 0.5 m a minute (the first guesses; the flights' own logs: PX4_SIH_FITTED in
quad_bringup.emulated.offline_chain). The wander starts at 0 (the estimator initialised
where the vehicle stands). Defaults (lag 0, no wander): the estimate is the truth.

What the autopilot publishes is smooth: EKF2's output predictor propagates the estimate with the IMU at the
current time and spreads each correction of its delayed filter over EKF2_TAU_POS (0.25 s, ekf2_params; the
complementary filter of EKF2's output_predictor), so the published position never jumps by a correction. The
Gauss-Markov process alone moves by white increments (at 100 Hz, 1 cm per tick at 0.6 m / 60 s: a 1.6 cm
jitter per 50 Hz odometry sample, which doubled the flown path's length and reached the position loop as noise);
here it passes through a first-order filter of time constant smoothing_s (default OUTPUT_TAU_S), its input scaled
by sqrt((tau + smoothing_s) / tau) so that the wander's RMS stays sigma. On PX4 SIH's flights the error's power
above 0.5 Hz is smaller than EKF2_TAU_POS alone gives (the delayed filter smooths its GPS too): band RMS 0.5-2 Hz
/ 0.05-0.5 Hz 0.07-0.15, 2-10 Hz / 0.5-2 Hz 0.12-0.22, where 0.25 s gives 0.24 and 0.18; WANDER_SMOOTHING_PX4_SIH_S
(0.7 s) gives 0.13 and 0.15.

Velocity noise (`velocity_noise_mps`, off by default): EKF2's output predictor (output_predictor.cpp) integrates
the IMU's delta velocities at the IMU rate and pulls the result toward the delayed filter's velocity with the
time constant EKF2_TAU_VEL (0.25 s, ekf2_params). PX4 SIH's accelerometer carries white noise of 0.5, 1.7 and
1.4 m/s^2 (body x, y, z, per sample, while thrusting: sih.cpp reconstruct_sensors_signals), sampled at 200 Hz in
SITL's lockstep loop (sih.cpp lockstep_loop: min(IMU_GYRO_RATEMAX 400, IMU_INTEG_RATE 200)). Integrated and
pulled back that way, the published velocity wanders off the delayed filter's as a first-order Gauss-Markov
process of time constant EKF2_TAU_VEL and standard deviation sigma_a sqrt(dt tau / 2): 0.0125, 0.0425, 0.035 m/s
(SIH_VELOCITY_NOISE_MPS; the delayed filter's own, slower velocity error comes on top and is not modelled). The
noise is on the body axes (the accelerometer's), rotated into the world by the attitude now; the position is not
touched (its wander is the measured one above).

Velocity wander (`velocity_wander_mps` horizontal / `velocity_wander_z_mps` vertical, correlation time
`velocity_wander_tau_s`; off by default): the delayed filter's own, slower velocity error, a first-order
Gauss-Markov process per world axis stepped as the position's wander. PX4 v1.16 SIH (EKF2 - SIH truth over four
flights): 0.1-0.32 m/s RMS horizontally, 0.14-0.19 m/s vertically, almost all below 0.5 Hz, autocorrelation time
2-5 s; the published velocity is not the published position's derivative (0.2 m/s RMS apart), so the two wander
independently here.

External vision (`vision_axes`, per world axis): where the autopilot's parameters make the received poses the
position source, the position on those axes is quad_vehicle_emu.external_vision's fusion of them (the truth now
plus the correction the last fused pose made), not the truth lagged and wandering: GPS lag and wander do not apply
there. Velocity, attitude and rates are as above.
"""

import collections
import math

import numpy as np

from quad_common import rotations
from quad_common.types import State
from quad_vehicle_emu.external_vision import VisionFusion

OUTPUT_TAU_S = 0.25   # PX4 EKF2_TAU_POS: the output predictor's position correction time constant
WANDER_SMOOTHING_PX4_SIH_S = 0.7   # the wander's smoothing that fits PX4 SIH's error spectrum (docstring)
VELOCITY_TAU_S = 0.25   # PX4 EKF2_TAU_VEL: the output predictor's velocity correction time constant
SIH_ACCEL_NOISE_MPS2 = (0.5, 1.7, 1.4)   # sih.cpp reconstruct_sensors_signals, body x y z, thrusting
SIH_IMU_DT_S = 1.0 / 200.0               # sih.cpp lockstep_loop: min(IMU_GYRO_RATEMAX, IMU_INTEG_RATE) = 200 Hz
SIH_VELOCITY_NOISE_MPS = tuple(a * math.sqrt(SIH_IMU_DT_S * VELOCITY_TAU_S / 2.0) for a in SIH_ACCEL_NOISE_MPS2)


class Estimate:
    def __init__(self, lag_s: float = 0.0, wander_m: float = 0.0, wander_z_m: float = 0.0, tau_s: float = 60.0,
                 seed: int = 0, velocity_noise_mps=(0.0, 0.0, 0.0), velocity_wander_mps: float = 0.0,
                 velocity_wander_z_mps: float = 0.0, velocity_wander_tau_s: float = 3.0,
                 vision_timeout_s: float = 5.0, smoothing_s: float = OUTPUT_TAU_S):
        for name, value in (('--estimator-lag-s', lag_s), ('--estimator-wander-m', wander_m),
                            ('--estimator-wander-z-m', wander_z_m)):
            if not (math.isfinite(value) and 0.0 <= value <= 10.0):
                raise ValueError(f'{name} = {value!r} must be a number in [0, 10]')
        if not (math.isfinite(tau_s) and tau_s > 0.0):
            raise ValueError(f'--estimator-wander-tau-s = {tau_s!r} must be a number > 0')
        if not (math.isfinite(smoothing_s) and 0.0 < smoothing_s <= 10.0):
            raise ValueError(f'--estimator-wander-smoothing-s = {smoothing_s!r} must be a number in (0, 10]')
        self.smoothing_s = float(smoothing_s)
        noise = np.asarray(velocity_noise_mps, dtype=float).reshape(-1)
        if noise.shape != (3,) or not np.all(np.isfinite(noise)) or np.any(noise < 0.0) or np.any(noise > 1.0):
            raise ValueError(f'--estimator-velocity-noise-mps = {noise.tolist()} must be three numbers in [0, 1] '
                             f'(body x, y, z; PX4 SIH: {", ".join(f"{v:.4f}" for v in SIH_VELOCITY_NOISE_MPS)})')
        self.velocity_sigma = noise
        for name, value in (('--estimator-velocity-wander-mps', velocity_wander_mps),
                            ('--estimator-velocity-wander-z-mps', velocity_wander_z_mps)):
            if not (math.isfinite(value) and 0.0 <= value <= 2.0):
                raise ValueError(f'{name} = {value!r} must be a number in [0, 2]')
        if not (math.isfinite(velocity_wander_tau_s) and velocity_wander_tau_s > 0.0):
            raise ValueError(f'--estimator-velocity-wander-tau-s = {velocity_wander_tau_s!r} must be a number > 0')
        self.velocity_wander_sigma = np.array([velocity_wander_mps, velocity_wander_mps, velocity_wander_z_mps])
        self.velocity_wander_tau_s = float(velocity_wander_tau_s)
        self.velocity_wander = np.zeros(3)
        self._velocity_wander_rng = np.random.default_rng([seed, 2])   # its own stream: the others are unchanged
        self.velocity_noise_body = np.zeros(3)
        self._velocity_rng = np.random.default_rng([seed, 1])   # its own stream: a seed's wander is unchanged
        self.lag_s, self.tau_s = float(lag_s), float(tau_s)
        self.sigma = np.array([wander_m, wander_m, wander_z_m], dtype=float)
        self.rng = np.random.default_rng(seed)
        self.wander = np.zeros(3)   # initialised where the vehicle stands, wandering from there
        self._raw = np.zeros(3)     # the Gauss-Markov process before the output predictor's smoothing
        self._raw_sigma = self.sigma * math.sqrt((self.tau_s + self.smoothing_s) / self.tau_s)
        self.last_s = None
        self._history = collections.deque()   # (time s, position) of the truth
        self.vision = VisionFusion(vision_timeout_s)   # fused external-vision poses (fuse_vision)

    def fuse_vision(self, position_enu, fusion_time_s: float):
        """A received external-vision pose (world ENU), fused as measured at fusion_time_s (this clock)."""
        self.vision.fuse(position_enu, fusion_time_s)

    def step(self, now_s: float, truth: State, vision_axes=(False, False, False)) -> State:
        """The estimate at now_s, given the truth now (call once per loop tick, times increasing); vision_axes:
        the world ENU axes whose position comes from the fused external-vision poses."""
        if self.last_s is not None and self.sigma.any():
            dt_s = max(now_s - self.last_s, 0.0)
            a = math.exp(-dt_s / self.tau_s)
            self._raw = a * self._raw + self._raw_sigma * math.sqrt(1.0 - a * a) * self.rng.standard_normal(3)
            self.wander += (self._raw - self.wander) * (1.0 - math.exp(-dt_s / self.smoothing_s))
        if self.last_s is not None and self.velocity_sigma.any():
            a = math.exp(-max(now_s - self.last_s, 0.0) / VELOCITY_TAU_S)
            self.velocity_noise_body = (a * self.velocity_noise_body + self.velocity_sigma * math.sqrt(1.0 - a * a)
                                        * self._velocity_rng.standard_normal(3))
        if self.last_s is not None and self.velocity_wander_sigma.any():
            a = math.exp(-max(now_s - self.last_s, 0.0) / self.velocity_wander_tau_s)
            self.velocity_wander = (a * self.velocity_wander + self.velocity_wander_sigma * math.sqrt(1.0 - a * a)
                                    * self._velocity_wander_rng.standard_normal(3))
        self.last_s = now_s
        self._history.append((now_s, truth.position.copy()))
        while len(self._history) > 1 and self._history[1][0] <= now_s - self.lag_s:
            self._history.popleft()
        _, position = self._history[0]
        vision_axes = np.asarray(vision_axes, dtype=bool).reshape(3)
        vision_position = self.vision.step(now_s, truth.position, self.velocity_wander)
        if vision_axes.any():
            position = np.where(vision_axes, vision_position, position + self.wander)
        else:
            position = position + self.wander
        if (not vision_axes.any() and not self.lag_s and not self.sigma.any() and not self.velocity_sigma.any()
                and not self.velocity_wander_sigma.any()):
            return truth
        velocity = truth.velocity + self.velocity_wander
        if self.velocity_sigma.any():
            velocity = velocity + rotations.to_matrix(truth.quaternion) @ self.velocity_noise_body
        return State(position=position, velocity=velocity, quaternion=truth.quaternion,
                     body_rates=truth.body_rates)
