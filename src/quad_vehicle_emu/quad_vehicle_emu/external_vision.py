"""External vision in the autopilot's estimator: the instant each received pose is fused at, and the position
estimate fused from the poses.

The fusion instant (the autopilot's boot time):
- PX4: src/modules/mavlink/mavlink_receiver.cpp (handle_message_odometry, handle_message_vision_position_estimate)
  sets timestamp_sample = _mavlink_timesync.sync_stamp(time_usec); src/modules/ekf2/EKF/estimator_interface.cpp
  (setExternalVisionData) fuses it at timestamp_sample - EKF2_EV_DELAY - dt_ekf / 2. sync_stamp
  (src/lib/timesync/Timesync.cpp) is the arrival time until CONVERGENCE_WINDOW (500) TIMESYNC round trips
  under MAX_RTT_SAMPLE (10 ms) have gone through its filter, then time_usec + the offset it measured against
  the clock the companion answers PX4's TIMESYNC requests with: before that the stamp is not read at all, after
  it the stamp must be in that clock.
- ArduPilot: libraries/GCS_MAVLink/GCS_Common.cpp (handle_vision_position_estimate, handle_odometry) maps usec to
  local time with correct_offboard_timestamp_usec_to_ms, libraries/AP_RTC/JitterCorrection.cpp: the offset is
  the smallest arrival - stamp seen (taken afresh over every 100 samples, a stamp at most 500 ms old), so the
  freshest sample counts as having arrived at once and only the stamps' jitter reaches the EKF, never their
  constant offset; libraries/AP_NavEKF3/AP_NavEKF3_Measurements.cpp (writeExtNavData) fuses it at that time -
  VISO_DELAY_MS - the filter step / 2.

The estimate: the EKF fuses the pose against its state at the fusion instant and its output predictor carries the
correction forward with the IMU (here: the vehicle's true motion), so the position estimate is
    p_est(now) = p_true(now) + c,  c -> p_pose - p_true(t_fusion)
c approaching each new innovation as a first order of time constant OUTPUT_TAU_S (EKF2_TAU_POS, the output
predictor's complementary filter), set at once on the first pose and on the first after a gap longer than the
position timeout (EKF2 and EKF3 reset their position to the vision position when its fusion starts). A pose whose
fusion instant matches the instant it was measured (the delay parameter = the pose's true age) leaves c = the
pose's own error; a delay d off leaves c = v d while moving at v. With no pose for CORRECTION_SPREAD_S the last
correction is spent: c integrates the published velocity's error (dead reckoning) until the position timeout.
"""

import collections
import math

import numpy as np

OUTPUT_TAU_S = 0.25          # PX4 EKF2_TAU_POS (ekf2 module.yaml): the output predictor's position time constant
CORRECTION_SPREAD_S = 3.0 * OUTPUT_TAU_S   # a correction is 95 % applied after this long
TRUTH_HISTORY_S = 1.0        # the delayed horizon's reach: a pose older than this is fused as this old

# PX4 src/lib/timesync/Timesync.hpp
PX4_CONVERGENCE_WINDOW = 500
PX4_MAX_RTT_SAMPLE_US = 10_000
PX4_MAX_DEVIATION_SAMPLE_US = 100_000
PX4_MAX_CONSECUTIVE_HIGH_DEVIATION = 5
PX4_ALPHA_GAIN_INITIAL = PX4_BETA_GAIN_INITIAL = 0.05
PX4_ALPHA_GAIN_FINAL = PX4_BETA_GAIN_FINAL = 0.003
PX4_HALF_EKF_DT_US = 5_000   # estimator_interface.cpp: _dt_ekf_avg * 5e5 with EKF2's 10 ms update period
# libraries/AP_RTC/JitterCorrection.h defaults, GCS_MAVLINK's lag_correction
ARDUPILOT_MAX_LAG_MS = 500
ARDUPILOT_CONVERGENCE_LOOPS = 100
ARDUPILOT_HALF_EKF_STEP_US = 1_000   # writeExtNavData: localFilterTimeStep_ms / 2 (EKF3 at 400 Hz: 2 ms / 2)


class Px4Timesync:
    """PX4's TIMESYNC filter (Timesync::update / add_sample / sync_stamp), all times in us."""

    def __init__(self):
        self.reset()

    def reset(self):
        self.sequence, self.offset_us, self.skew_us = 0, 0.0, 0.0
        self.alpha, self.beta = PX4_ALPHA_GAIN_INITIAL, PX4_BETA_GAIN_INITIAL
        self.high_deviation_count = 0

    @property
    def converged(self) -> bool:
        return self.sequence >= PX4_CONVERGENCE_WINDOW

    def update(self, now_us: int, remote_ns: int, originate_ns: int):
        """An answer to PX4's own TIMESYNC request: tc1 = remote_ns (the companion's clock), ts1 = originate_ns
        (PX4's clock when asked), arriving at now_us."""
        offset_us = (originate_ns // 1000 + now_us - (remote_ns // 1000) * 2) // 2
        rtt_us = now_us - originate_ns // 1000
        if rtt_us >= PX4_MAX_RTT_SAMPLE_US:
            return
        if self.converged and abs(self.offset_us - offset_us) > PX4_MAX_DEVIATION_SAMPLE_US:
            self.high_deviation_count += 1
            if self.high_deviation_count > PX4_MAX_CONSECUTIVE_HIGH_DEVIATION:
                self.reset()
            return
        if not self.converged:   # gain scheduling: a sigmoid from the initial to the final gains
            progress = self.sequence / PX4_CONVERGENCE_WINDOW
            p = 1.0 - math.exp(0.5 * (1.0 - 1.0 / (1.0 - progress)))
            self.alpha = p * PX4_ALPHA_GAIN_FINAL + (1.0 - p) * PX4_ALPHA_GAIN_INITIAL
            self.beta = p * PX4_BETA_GAIN_FINAL + (1.0 - p) * PX4_BETA_GAIN_INITIAL
        else:
            self.alpha, self.beta = PX4_ALPHA_GAIN_FINAL, PX4_BETA_GAIN_FINAL
        previous = self.offset_us
        if self.sequence == 0:
            self.offset_us = float(offset_us)
        else:
            self.offset_us = self.alpha * offset_us + (1.0 - self.alpha) * (self.offset_us + self.skew_us)
            self.skew_us = self.beta * (self.offset_us - previous) + (1.0 - self.beta) * self.skew_us
        self.sequence += 1
        self.high_deviation_count = 0

    def sync_stamp(self, stamp_us: int, arrival_us: int) -> int:
        """The message's time in PX4's clock: the arrival until converged, then the stamp + the offset."""
        return int(stamp_us + self.offset_us) if self.converged else int(arrival_us)


class JitterCorrection:
    """ArduPilot's JitterCorrection::correct_offboard_timestamp_usec, all times in us."""

    def __init__(self, max_lag_ms: int = ARDUPILOT_MAX_LAG_MS, convergence_loops: int = ARDUPILOT_CONVERGENCE_LOOPS):
        self.max_lag_us, self.convergence_loops = max_lag_ms * 1000, convergence_loops
        self.link_offset_us, self.initialised = 0, False
        self.min_sample_us, self.min_sample_counter = 0, 0

    def correct(self, stamp_us: int, local_us: int) -> int:
        diff_us = int(local_us) - int(stamp_us)
        if not self.initialised or diff_us < self.link_offset_us:   # not from the future: lower the offset
            self.link_offset_us, self.initialised = diff_us, True
        estimate_us = int(stamp_us) + self.link_offset_us
        if estimate_us + self.max_lag_us < local_us:                  # older than max_lag: clamp
            estimate_us = int(local_us) - self.max_lag_us
            self.link_offset_us = estimate_us - int(stamp_us)
        if self.min_sample_counter == 0:
            self.min_sample_us = diff_us
        self.min_sample_counter += 1
        self.min_sample_us = min(self.min_sample_us, diff_us)
        if self.min_sample_counter == self.convergence_loops:         # follow drift: the window's minimum
            self.link_offset_us, self.min_sample_counter = self.min_sample_us, 0
        return estimate_us


class VisionClock:
    """The boot time (us) at which the autopilot's EKF fuses a pose stamped stamp_us that arrived at arrival_us
    (both in the autopilot's boot clock), with the delay parameter delay_ms (EKF2_EV_DELAY / VISO_DELAY_MS)."""

    def __init__(self, flavour: str):
        if flavour not in ('px4', 'ardupilot'):
            raise ValueError(f'autopilot = {flavour!r}: px4 or ardupilot')
        self.flavour = flavour
        self.timesync = Px4Timesync()
        self.jitter = JitterCorrection()

    def fusion_us(self, stamp_us: int, arrival_us: int, delay_ms: float) -> int:
        if self.flavour == 'px4':
            return self.timesync.sync_stamp(stamp_us, arrival_us) - int(delay_ms * 1000) - PX4_HALF_EKF_DT_US
        local_us = self.jitter.correct(stamp_us, arrival_us)
        return local_us - int(delay_ms * 1000) - ARDUPILOT_HALF_EKF_STEP_US


class VisionFusion:
    """The position estimate fused from external-vision poses (module docstring). Times in seconds (one clock),
    positions world ENU."""

    def __init__(self, reset_after_s: float):
        self.reset_after_s = float(reset_after_s)
        self.correction = np.zeros(3)
        self._target = None
        self._pending = []                         # (fusion time, position)
        self._truth = collections.deque()          # (time, position)
        self.last_fused_s = None
        self.last_step_s = None

    def fuse(self, position_enu, fusion_time_s: float):
        position = np.asarray(position_enu, dtype=float).reshape(3)
        if not (np.all(np.isfinite(position)) and math.isfinite(fusion_time_s)):
            raise ValueError(f'external vision position {position.tolist()} at {fusion_time_s!r} s not finite')
        self._pending.append((float(fusion_time_s), position))

    def truth_at(self, t_s: float) -> np.ndarray:
        """The truth's position at t_s, linear between the recorded ticks (held beyond them)."""
        times = [t for t, _ in self._truth]
        k = int(np.searchsorted(times, t_s))
        if k == 0:
            return self._truth[0][1]
        if k >= len(times):
            return self._truth[-1][1]
        (t0, p0), (t1, p1) = self._truth[k - 1], self._truth[k]
        return p0 + (p1 - p0) * ((t_s - t0) / (t1 - t0))

    def step(self, now_s: float, truth_position, velocity_error=(0.0, 0.0, 0.0)) -> np.ndarray:
        """The position estimate at now_s (call once per tick, times increasing)."""
        self._truth.append((now_s, np.array(truth_position, dtype=float)))
        while len(self._truth) > 2 and self._truth[1][0] < now_s - TRUTH_HISTORY_S:
            self._truth.popleft()
        dt_s = 0.0 if self.last_step_s is None else max(now_s - self.last_step_s, 0.0)
        self.last_step_s = now_s
        due = [(t, p) for t, p in self._pending if t <= now_s]
        self._pending = [(t, p) for t, p in self._pending if t > now_s]   # a future stamp waits for its time
        for t_fusion, position in sorted(due, key=lambda s: s[0]):
            innovation = position - self.truth_at(t_fusion)
            if self.last_fused_s is None or now_s - self.last_fused_s > self.reset_after_s:
                self.correction = innovation.copy()   # fusion (re)starts: the position is reset to the pose
            self._target, self.last_fused_s = innovation, now_s
        self.correction = self.correction + np.asarray(velocity_error, dtype=float) * dt_s
        if self._target is not None and now_s - self.last_fused_s <= CORRECTION_SPREAD_S:
            self.correction += (self._target - self.correction) * (1.0 - math.exp(-dt_s / OUTPUT_TAU_S))
        return np.asarray(truth_position, dtype=float) + self.correction
