"""Autopilot time -> local (ROS) time, so telemetry is stamped with when it was measured, not when it arrived.

Two estimates of offset = local - autopilot (ns):
- TIMESYNC: we send ts1 = local time; the autopilot answers tc1 = its boot time in ns (PX4 Timesync,
  ArduPilot GCS_MAVLINK::handle_timesync); offset = (ts1 + t_reply) / 2 - tc1, taken from the reply with the
  shortest round trip among the recent ones.
- Minimum-delay filter: every timestamped message gives arrival - time; the smallest over a sliding window
  is the offset plus the smallest transport delay.
TIMESYNC is used while it agrees with the message times (its stamps never after an arrival, nor more than
max_disagreement_s before the earliest); otherwise the filter. jitter_ms is the standard deviation of the
chosen estimate's recent samples.

Thread-safe: the receive thread feeds it while diagnostics (the supervisor, the services) read it; every method
holds one lock (iterating a window while the receive thread appended to it raised "deque mutated during
iteration" and killed the bridge in `offboard`, issue 28).
"""

import collections
import math
import threading

import numpy as np

# TIMESYNC is dropped when the message times put it this much before the earliest arrival: far above the
# telemetry latency and ArduPilot's bursts (20-65 ms), far below an unrelated clock (seconds). At 50 ms the choice
# flipped with ArduPilot's 50 ms latency, and each flip moved odometry stamps back (out-of-order odometry).
MAX_DISAGREEMENT_S = 0.25
ONE_MS_NS = 1_000_000  # TIMESYNC may put a stamp this much after the earliest arrival (rounding, scheduling)


class ClockMapper:
    def __init__(self, window_s: float = 10.0, max_disagreement_s: float = MAX_DISAGREEMENT_S):
        self.window_ns = int(window_s * 1e9)
        self.max_disagreement_ns = int(max_disagreement_s * 1e9)
        self._oneway = collections.deque()   # (local arrival ns, arrival - remote ns)
        self._minima = collections.deque()   # monotone deque for the sliding minimum
        self._sync = collections.deque()     # (local ns, rtt ns, offset ns)
        self.source = 'none'
        self._last = {}                      # stream -> (remote us, local ns) of its last mapping
        self._lock = threading.Lock()

    def observe(self, remote_us: int, arrival_ns: int):
        """A message stamped remote_us (autopilot boot time, us) arrived at local arrival_ns."""
        sample = arrival_ns - int(remote_us) * 1000
        with self._lock:
            self._observe(sample, arrival_ns)

    def _observe(self, sample, arrival_ns):
        self._oneway.append((arrival_ns, sample))
        while self._minima and self._minima[-1][1] >= sample:
            self._minima.pop()
        self._minima.append((arrival_ns, sample))
        self._trim(arrival_ns)

    def timesync(self, ts1_local_ns: int, tc1_remote_ns: int, reply_local_ns: int):
        rtt = reply_local_ns - ts1_local_ns
        if rtt < 0 or tc1_remote_ns <= 0:
            return
        with self._lock:
            self._sync.append((reply_local_ns, rtt, (ts1_local_ns + reply_local_ns) // 2 - tc1_remote_ns))
            self._trim(reply_local_ns)

    def _trim(self, now_ns):
        horizon = now_ns - self.window_ns
        for q in (self._oneway, self._minima, self._sync):
            while len(q) > 1 and q[0][0] < horizon:
                q.popleft()

    def offset_ns(self) -> int | None:
        with self._lock:
            return self._offset_ns()

    def _offset_ns(self) -> int | None:
        floor = self._minima[0][1] if self._minima else None
        if self._sync:
            best = min(self._sync, key=lambda s: s[1])[2]
            if floor is None or -ONE_MS_NS <= floor - best <= self.max_disagreement_ns:
                self.source = 'timesync'
                return best
        if floor is None:
            self.source = 'none'
            return None
        self.source = 'arrival minimum filter'
        return floor

    def to_local_ns(self, remote_us: int, arrival_ns: int, stream=None) -> int:
        """Local time of a message stamped remote_us, never after its arrival and never before the stamp of an
        earlier-measured message of the same stream (an offset update must not put odometry out of order). Per
        stream: messages of different kinds carry different times of the same instant (PX4's HIGHRES_IMU
        time_usec is ahead of LOCAL_POSITION_NED's whole time_boot_ms), so one guard for all would skip."""
        with self._lock:
            offset = self._offset_ns()
            local = arrival_ns if offset is None else min(int(remote_us) * 1000 + offset, arrival_ns)
            last_remote, last_local = self._last.get(stream, (-1, -1))
            if remote_us >= last_remote and local < last_local:
                local = min(last_local, arrival_ns)
            self._last[stream] = (int(remote_us), local)
            return local

    def jitter_ms(self) -> float:
        with self._lock:
            samples = [s[2] for s in self._sync] if self.source == 'timesync' else [s[1] for s in self._oneway]
        return float(np.std(samples) / 1e6) if len(samples) > 1 else math.nan
