"""A motion-capture stand-in: the simulator's truth as a mocap system (Vicon, OptiTrack, Qualisys through a ROS 2
driver) publishes it: a pose per frame at rate_hz, stamped with the instant measured, delivered latency_s later,
with Gaussian noise and lost frames. No rclpy (sim_node wires it; docs/quad_sim.md).

Per frame k measured at t_k (the first truth instant offered at or after k / rate_hz; sim_node offers one per step,
so the frame rate is at most the step rate):
  position    p + n_p,            n_p ~ N(0, position_noise_m^2 I)   (position_noise_m: RMS per axis)
  attitude    q (x) [theta / 2, 1] normalised, theta ~ N(0, attitude_noise_rad^2 I)   (a small body-frame rotation)
  lost        a burst starts with probability dropout_probability at a frame; it loses that frame and every frame
              measured within dropout_burst_s after it (0: that frame only)
  delivered   at the first offered time >= t_k + latency_s; the message's stamp stays t_k
"""

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from quad_common import rotations


@dataclass(frozen=True)
class MocapConfig:
    rate_hz: float = 0.0                # frames per second of sim time; 0: off
    position_noise_m: float = 0.0       # RMS per axis
    attitude_noise_rad: float = 0.0     # RMS per axis of the body-frame error rotation
    latency_s: float = 0.0              # measured -> delivered
    dropout_probability: float = 0.0    # per frame: a burst of lost frames starts
    dropout_burst_s: float = 0.0        # a burst's length after its first lost frame; 0: one frame

    def __post_init__(self):
        for name, lo, hi in (('rate_hz', 0.0, 10000.0), ('position_noise_m', 0.0, 10.0),
                             ('attitude_noise_rad', 0.0, 1.0), ('latency_s', 0.0, 10.0),
                             ('dropout_probability', 0.0, 1.0), ('dropout_burst_s', 0.0, 60.0)):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and lo <= value <= hi):
                raise ValueError(f'mocap {name} = {value!r} refused: needs a number in [{lo}, {hi}]')

    @property
    def enabled(self) -> bool:
        return self.rate_hz > 0


@dataclass(frozen=True)
class MocapFrame:
    """One pose as the mocap system publishes it: stamp_ns is when it was measured (ENU world, FLU body, xyzw)."""
    stamp_ns: int
    position: np.ndarray
    quaternion: np.ndarray


class MotionCapture:
    """offer(t, truth) at increasing sim times; it returns the frames delivered by then, oldest first."""

    def __init__(self, config: MocapConfig, seed: int = 0):
        self.config = config
        self.seed = int(seed)
        self.reset()

    def reset(self):
        self._rng = np.random.default_rng([self.seed, 2])  # streams 0 and 1 are the simulator's gusts and noise
        self._next_frame_ns = 0
        self._frame_period_ns = int(round(1e9 / self.config.rate_hz)) if self.config.enabled else 0
        self._latency_ns = int(round(self.config.latency_s * 1e9))
        self._burst_until_ns = -1
        self._last_offered_ns = -1
        self._in_flight: deque[MocapFrame] = deque()
        self.frames_measured = 0
        self.frames_lost = 0

    def offer(self, time_ns: int, position, quaternion) -> list[MocapFrame]:
        """The truth at sim time time_ns; a time not after the last one offered measures nothing new."""
        if not self.config.enabled:
            return []
        if time_ns > self._last_offered_ns:
            self._last_offered_ns = time_ns
            if time_ns >= self._next_frame_ns:
                # the next frame on the rate grid after this instant (frames the caller's steps skipped are not made)
                self._next_frame_ns += ((time_ns - self._next_frame_ns) // self._frame_period_ns + 1) \
                    * self._frame_period_ns
                self._measure(time_ns, position, quaternion)
        delivered = []
        while self._in_flight and self._in_flight[0].stamp_ns + self._latency_ns <= time_ns:
            delivered.append(self._in_flight.popleft())
        return delivered

    def _measure(self, time_ns, position, quaternion):
        c, rng = self.config, self._rng
        self.frames_measured += 1
        noise_p = rng.standard_normal(3) * c.position_noise_m
        tilt = rng.standard_normal(3) * c.attitude_noise_rad
        starts_burst = rng.random() < c.dropout_probability
        if starts_burst and time_ns > self._burst_until_ns:
            self._burst_until_ns = time_ns + int(round(c.dropout_burst_s * 1e9))
        if time_ns <= self._burst_until_ns:
            self.frames_lost += 1
            return
        q = rotations.normalize(rotations.multiply(np.asarray(quaternion, float), np.append(0.5 * tilt, 1.0)))
        self._in_flight.append(MocapFrame(int(time_ns), np.asarray(position, float) + noise_p, q))
