"""An external pose (motion capture, vision) on its way to the autopilot's estimator: frame, time, rate, faults.

Frames (parameter external_pose_frame): enu or y_up (quad_common.mocap_frames), then converted once to NED/FRD
by quad_bridge.frames.

Time: the sample's stamp goes out as it is, in us: local ROS time, the system clock, which is the clock the bridge
answers the vehicle's TIMESYNC requests with (quad_bridge.clock.answer_clock_ns). PX4 maps a companion's time_usec
through the offset it learns from those answers once its filter has converged (Timesync::sync_stamp; the arrival
time until then), so the estimator fuses the pose at the instant it was measured; ArduPilot's JitterCorrection
keeps only the stamps' jitter, whatever their clock. A stamp in the autopilot's own boot time would map before
PX4's boot once its TIMESYNC converged, and EKF2 would stop fusing the pose.

Rate: a sample goes out when its stamp reaches the due time, which then advances by 1 / max_rate_hz (from the
sample's stamp after a gap): a faster stream is thinned to max_rate_hz on average, not to the next multiple of its
own period (PX4 EKF2 fuses external vision at up to ~30-50 Hz; ArduPilot's visual odometry at the rate
VISION_POSITION_ESTIMATE arrives).

Faults (each one line in diagnostics):
- late: now - stamp > max_age_s. The sample is dropped and counted, the hand-over goes on: the autopilot's
  estimator drops such a sample itself (EKF2 fuses an observation only within 100 ms of its fusion horizon, EKF3
  likewise within its buffer) and predicts on its IMU meanwhile; its position is lost only when no timely sample
  comes, which is the timeout;
- timeout: no timely sample for timeout_s (none at all, or only late ones): ends a hand-over;
- jump: |p - p_last| > max_speed_m_s * dt + jump_margin_m (a swapped rigid body, a reflection): ends a hand-over.
"""

import dataclasses
import math
import threading

import numpy as np

from quad_bridge import frames
from quad_common import mocap_frames, rotations

LATE = 'late'


def ends_handover(fault: str | None) -> bool:
    """Every fault but a late sample ends a hand-over (module docstring)."""
    return bool(fault) and not fault.startswith(LATE)


@dataclasses.dataclass(frozen=True)
class PoseNed:
    """One sample for the autopilot: world NED position (m), attitude body FRD -> NED (x,y,z,w), body FRD
    velocity (m/s) or None, and its time in the autopilot's boot clock (us)."""
    time_us: int
    position_ned: np.ndarray
    quaternion_ned_frd: np.ndarray
    velocity_frd: np.ndarray | None

    @property
    def velocity_ned(self):
        """v_NED = R(q_NED_FRD) v_FRD."""
        return None if self.velocity_frd is None else rotations.to_matrix(self.quaternion_ned_frd) @ self.velocity_frd


@dataclasses.dataclass
class ExternalPoseConfig:
    frame: str = 'enu'
    max_rate_hz: float = 30.0
    timeout_s: float = 0.5
    max_age_s: float = 0.2
    max_speed_m_s: float = 10.0
    jump_margin_m: float = 0.1

    def __post_init__(self):
        mocap_frames.check_frame(self.frame)
        for name in ('max_rate_hz', 'timeout_s', 'max_age_s', 'max_speed_m_s'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f'external pose {name} must be finite and > 0, got {value}')
        if not (math.isfinite(self.jump_margin_m) and self.jump_margin_m >= 0):
            raise ValueError(f'external pose jump_margin_m must be finite and >= 0, got {self.jump_margin_m}')


class ExternalPoseFilter:
    """Decides, per sample, forward / drop (rate) / reject (fault), and keeps what diagnostics report. Thread-safe:
    samples arrive on the executor's thread, the supervisor checks the timeout."""

    def __init__(self, config: ExternalPoseConfig):
        self.config = config
        self.fault = None           # the newest fault, one line, or None
        self.forwarded = 0
        self.dropped_rate = 0
        self.dropped_late = 0
        self._last_stamp_ns = None  # stamp of the last accepted sample (jump reference)
        self._last_position = None
        self._next_due_ns = None    # stamp from which the next sample may go out (rate)
        self._last_arrival_ns = None
        self._last_timely_arrival_ns = None   # arrival of the last sample no older than max_age_s (timeout)
        self._sent_times_ns = []    # arrival times of forwarded samples over the last second (rate)
        self.last_age_s = math.nan
        self._lock = threading.Lock()

    def offer(self, position, quaternion, velocity, stamp_ns: int, now_ns: int) -> PoseNed | None:
        """A sample measured at stamp_ns (local ROS time) arriving at now_ns: the PoseNed to send, or None."""
        with self._lock:
            return self._offer(position, quaternion, velocity, stamp_ns, now_ns)

    def _offer(self, position, quaternion, velocity, stamp_ns, now_ns):
        cfg = self.config
        self._last_arrival_ns = now_ns
        self.last_age_s = (now_ns - stamp_ns) / 1e9
        if self.last_age_s > cfg.max_age_s:
            self.dropped_late += 1
            self.fault = f'{LATE}: stamp {self.last_age_s * 1e3:.0f} ms old > {cfg.max_age_s * 1e3:.0f} ms'
            return None
        self._last_timely_arrival_ns = now_ns
        if not ends_handover(self.fault):
            self.fault = None   # the late fault lasts as long as late samples come
        p, q, v = mocap_frames.to_enu(cfg.frame, position, quaternion, velocity)
        if self._last_position is not None:
            dt = max(0.0, (stamp_ns - self._last_stamp_ns) / 1e9)
            step = float(np.linalg.norm(p - self._last_position))
            bound = cfg.max_speed_m_s * dt + cfg.jump_margin_m
            if step > bound:
                self.fault = f'jump: {step:.2f} m in {dt * 1e3:.0f} ms > {bound:.2f} m'
                return None
        self._last_position, self._last_stamp_ns = p, stamp_ns
        period_ns = int(1e9 / cfg.max_rate_hz)
        if self._next_due_ns is not None and stamp_ns < self._next_due_ns:
            self.dropped_rate += 1
            return None
        time_us = int(stamp_ns) // 1000   # the TIMESYNC answers' clock (module docstring)
        self.fault = None
        self._next_due_ns = (stamp_ns if self._next_due_ns is None else max(self._next_due_ns, stamp_ns - period_ns)) \
            + period_ns
        self.forwarded += 1
        self._sent_times_ns = [t for t in self._sent_times_ns if t > now_ns - 1_000_000_000] + [now_ns]
        return PoseNed(time_us, frames.world_enu_ned(p), frames.quaternion_enu_to_ned(q),
                       None if v is None else frames.body_flu_frd(v))

    def check_timeout(self, now_ns: int) -> str | None:
        """The timeout fault once no timely sample came for timeout_s (silent, only late ones, or never started),
        else the current one."""
        with self._lock:
            return self._check_timeout(now_ns)

    def _check_timeout(self, now_ns):
        timeout_ns = self.config.timeout_s * 1e9
        if self._last_timely_arrival_ns is None or now_ns - self._last_timely_arrival_ns > timeout_ns:
            if self._last_arrival_ns is None:
                silent = 'never received'
            elif now_ns - self._last_arrival_ns > timeout_ns:
                silent = f'no sample for {(now_ns - self._last_arrival_ns) / 1e9:.2f} s'
            else:
                since = 'ever' if self._last_timely_arrival_ns is None else \
                    f'for {(now_ns - self._last_timely_arrival_ns) / 1e9:.2f} s'
                silent = f'no timely sample {since} (the newest {self.last_age_s * 1e3:.0f} ms old)'
            self.fault = f'timeout: {silent} (> {self.config.timeout_s:.2f} s)'
        return self.fault

    def rate_hz(self, now_ns: int) -> float:
        """Samples forwarded over the last second."""
        with self._lock:
            return self._rate_hz(now_ns)

    def _rate_hz(self, now_ns):
        return float(sum(1 for t in self._sent_times_ns if t > now_ns - 1_000_000_000))
