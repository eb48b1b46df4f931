"""Autopilot time -> local (ROS) time, so telemetry is stamped with when it was measured, not when it arrived.

The autopilot's clock need not run at our rate (PX4 SIH ran at 0.984-0.993 of wall time, 0.93 under load; a
crystal drifts by tens of ppm), so the offset = local - autopilot (ns) is a line in autopilot time:
    offset(r) = offset_ref + drift * (r - r_ref),    drift = (our rate / its rate) - 1,
fitted by least squares over the last window_s, from either of
- TIMESYNC: we send ts1 = local time; the autopilot answers tc1 = its boot time in ns (PX4 Timesync,
  ArduPilot GCS_MAVLINK::handle_timesync); each answer gives offset (ts1 + t_reply) / 2 - tc1 at tc1, good to
  half its round trip: the line is fitted through the answers whose round trip is within 2x + 1 ms of the
  shortest one (fewer than MIN_FIT_POINTS over MIN_FIT_SPAN_S: the shortest one, carried by the other line's
  drift).
- Minimum-delay filter: every timestamped message gives arrival - time = offset + its transport delay; the
  smallest per BUCKET_S of autopilot time lie on offset + the smallest delay: the line through them (points more
  than OUTLIER_NS above the first fit dropped, refitted) is the offset plus that smallest delay.
A single minimum over the window (what this was before) is the oldest sample when the autopilot's clock runs
slow: stamps came out early by drift x window (70-150 ms on PX4 SIH), and TIMESYNC, which does not drift, was
rejected against it. TIMESYNC is used while it agrees with the message times at the newest message (its stamps
never after an arrival, nor more than max_disagreement_s before the earliest); otherwise the filter. The choice
has hysteresis: a switch needs the other source to be the better one for SWITCH_PERSIST_S without a break, and
TIMESYNC is left only when its stamps fall HYSTERESIS_NS further after the arrivals than the bound that admits it
(at once only for a gross disagreement, beyond max_disagreement_s either way): on PX4 SIH the plain rule flipped
11-17 times a flight, each flip a step of a few ms in the stamps. jitter_ms is the standard deviation of the
chosen estimate's samples about its line; drift_ppm its drift.

Thread-safe: the receive thread feeds it while diagnostics (the supervisor, the services) read it; every method
holds one lock (iterating a window while the receive thread appended to it raised "deque mutated during
iteration" and killed the bridge in `offboard`).
"""

import collections
import math
import statistics
import threading
import time

import numpy as np

# TIMESYNC is dropped when the message times put it this much before the earliest arrival: far above the
# telemetry latency and ArduPilot's bursts (20-65 ms), far below an unrelated clock (seconds). At 50 ms the choice
# flipped with ArduPilot's 50 ms latency, and each flip moved odometry stamps back (out-of-order odometry).
MAX_DISAGREEMENT_S = 0.25
ONE_MS_NS = 1_000_000  # TIMESYNC may put a stamp this much after the earliest arrival (rounding, scheduling)
BUCKET_S = 0.25        # the minimum-delay filter keeps one minimum per this much autopilot time
MIN_FIT_POINTS = 4     # a drift is fitted from this many points ...
MIN_FIT_SPAN_S = 2.0   # ... spanning this much autopilot time (else the offset is taken as constant)
OUTLIER_NS = 2_000_000  # a bucket minimum this far above the line was a delayed bucket (a stall, a burst)
MAX_DRIFT = 0.2        # a fitted drift beyond 20 % (PX4 SIH under load: 7.5 %) is noise, not a clock
SWITCH_PERSIST_S = 2.0  # the other clock source must be the better one this long (our time) before a switch
HYSTERESIS_NS = 1_000_000  # TIMESYNC is kept until its stamps are this much beyond the bound that admits it
TIMESYNC, FILTER = 'timesync', 'arrival minimum filter'


def _line(remote_ns, offset_ns):
    """(r_ref, offset at r_ref, drift, residuals, drift standard error) of the least-squares line
    offset = a + drift (r - r_ref), r_ref the newest point; drift 0 (standard error inf) and the smallest offset
    when the points are too few, too close together, or say a drift no clock has. On Python numbers: the window
    holds at most ~40 points and the line is refitted ~20 times a second (every new bucket minimum), where
    numpy's per-call overhead would dominate the receive thread's clock work."""
    r_ref, off_ref = int(remote_ns[-1]), int(min(offset_ns))
    x = [(r - r_ref) / 1e9 for r in remote_ns]
    y = [float(o - off_ref) for o in offset_ns]
    n = len(x)
    if n < MIN_FIT_POINTS or max(x) - min(x) < MIN_FIT_SPAN_S:
        return r_ref, off_ref, 0.0, y, math.inf
    x_mean, y_mean = sum(x) / n, sum(y) / n
    dx = [xi - x_mean for xi in x]
    sxx = sum([d * d for d in dx])
    slope = sum([d * yi for d, yi in zip(dx, y)]) / sxx    # least squares in closed form
    intercept = y_mean - slope * x_mean
    residuals = [yi - (intercept + slope * xi) for xi, yi in zip(x, y)]
    se = math.sqrt(sum([e * e for e in residuals]) / (n - 2) / sxx) / 1e9
    if abs(slope / 1e9) > MAX_DRIFT:
        return r_ref, off_ref, 0.0, y, math.inf
    return r_ref, off_ref + int(round(intercept)), float(slope) / 1e9, residuals, se


class ClockMapper:
    def __init__(self, window_s: float = 10.0, max_disagreement_s: float = MAX_DISAGREEMENT_S):
        self.window_ns = int(window_s * 1e9)
        self.max_disagreement_ns = int(max_disagreement_s * 1e9)
        self.bucket_ns = int(BUCKET_S * 1e9)
        self._oneway = collections.deque()   # (local arrival ns, remote ns, arrival - remote ns): jitter
        self._minima = collections.deque()   # [bucket, remote ns, arrival - remote ns] smallest per bucket
        self._sync = collections.deque()     # (local ns, rtt ns, remote ns, offset ns)
        self._fits = None                    # cached (floor line, sync line) until the next sample
        self.source = 'none'
        self.switches = 0                    # changes between TIMESYNC and the filter (diagnostics)
        self._other_since_ns = None          # since when the other source has been the better one, or None
        self._compared = False               # the first choice with the filter's drift fitted is made
        self._now_ns = 0                     # the newest local time seen (an arrival or a TIMESYNC reply)
        self._last = {}                      # stream -> (remote us, local ns) of its last mapping
        self._lock = threading.Lock()

    def observe(self, remote_us: int, arrival_ns: int):
        """A message stamped remote_us (autopilot boot time, us) arrived at local arrival_ns."""
        with self._lock:
            self._observe(remote_us, arrival_ns)

    def _observe(self, remote_us, arrival_ns):
        remote_ns = int(remote_us) * 1000
        sample = arrival_ns - remote_ns
        bucket = remote_ns // self.bucket_ns
        self._oneway.append((arrival_ns, remote_ns, sample))
        self._now_ns = max(self._now_ns, arrival_ns)
        minima = self._minima
        if minima and remote_ns < minima[-1][1] - self.window_ns:   # the autopilot rebooted
            minima.clear()
            self._sync.clear()
            self._compared = False
        if minima and minima[-1][0] == bucket:
            if sample < minima[-1][2]:
                minima[-1][1:] = [remote_ns, sample]
                self._fits = None
        elif not minima or bucket > minima[-1][0]:
            minima.append([bucket, remote_ns, sample])
            self._fits = None
        self._trim(arrival_ns)

    def timesync(self, ts1_local_ns: int, tc1_remote_ns: int, reply_local_ns: int):
        rtt = reply_local_ns - ts1_local_ns
        if rtt < 0 or tc1_remote_ns <= 0:
            return
        with self._lock:
            offset = (ts1_local_ns + reply_local_ns) // 2 - tc1_remote_ns
            self._sync.append((reply_local_ns, rtt, tc1_remote_ns, offset))
            self._now_ns = max(self._now_ns, reply_local_ns)
            self._fits = None
            self._trim(reply_local_ns)

    def _trim(self, now_ns):
        horizon = now_ns - self.window_ns
        while len(self._oneway) > 1 and self._oneway[0][0] < horizon:
            self._oneway.popleft()
        newest_remote = self._oneway[-1][1] if self._oneway else None
        while newest_remote is not None and len(self._minima) > 1 and \
                self._minima[0][1] < newest_remote - self.window_ns:
            self._minima.popleft()
            self._fits = None
        while len(self._sync) > 1 and self._sync[0][0] < horizon:
            self._sync.popleft()
            self._fits = None

    # --- the two lines ---------------------------------------------------------------------------------

    def _floor_line(self):
        if not self._minima:
            return None
        remote = [m[1] for m in self._minima]
        offset = [m[2] for m in self._minima]
        fit = _line(remote, offset)
        if math.isfinite(fit[4]):   # drop delayed buckets, refit on the lower envelope
            bound = statistics.median(fit[3]) + OUTLIER_NS
            keep = [i for i, e in enumerate(fit[3]) if e <= bound]
            if len(keep) >= MIN_FIT_POINTS:
                fit = _line([remote[i] for i in keep], [offset[i] for i in keep])
        return fit

    def _sync_line(self, floor):
        """TIMESYNC's line; when its drift is known worse than the filter's (too few answers, or round trips
        long and uneven on a loaded machine: 0.3-0.6 s gave +21000 ppm on a clock without drift), the answer
        with the shortest round trip carried by the filter's drift (the drift is one fact of the two clocks)."""
        if not self._sync:
            return None
        shortest = min(s[1] for s in self._sync)
        good = [s for s in self._sync if s[1] <= 2 * shortest + ONE_MS_NS]
        fit = _line([s[2] for s in good], [s[3] for s in good])
        if floor is not None and floor[4] < fit[4]:
            best = min(good, key=lambda s: s[1])
            return best[2], best[3], floor[2], fit[3], floor[4]
        return fit

    def _lines(self):
        if self._fits is None:
            floor = self._floor_line()
            self._fits = (floor, self._sync_line(floor))
        return self._fits

    def _chosen(self):
        """The line in use (r_ref, offset_ref, drift, residuals, drift standard error), or None; sets source."""
        floor, sync = self._lines()
        if sync is None or floor is None:
            self.source, self._other_since_ns = (TIMESYNC if sync else 'none' if floor is None else FILTER), None
            return sync or floor
        at = max(floor[0], sync[0])
        gap = _at(floor, at) - _at(sync, at)   # how far TIMESYNC's stamps lie before the earliest arrivals
        better = self._better(gap)
        if not self._compared or (better == FILTER and not (
                -self.max_disagreement_ns <= gap <= self.max_disagreement_ns)):
            # at once: before the filter's drift is fitted (the gap is not yet known), the first choice after it, or
            # a gross disagreement
            self._compared = math.isfinite(floor[4])
            self._switch(better)
        elif better == self.source:
            self._other_since_ns = None
        elif self._other_since_ns is None:
            self._other_since_ns = self._now_ns
        elif self._now_ns - self._other_since_ns >= SWITCH_PERSIST_S * 1e9:
            self._switch(better)
        return sync if self.source == TIMESYNC else floor

    def _better(self, gap_ns) -> str:
        """TIMESYNC while its stamps are never after an arrival (1 ms slack; HYSTERESIS_NS more to stay on it) nor
        more than max_disagreement_s before the earliest; else the filter."""
        after_ns = ONE_MS_NS + (HYSTERESIS_NS if self.source == TIMESYNC else 0)
        return TIMESYNC if -after_ns <= gap_ns <= self.max_disagreement_ns else FILTER

    def _switch(self, source):
        self.switches += self.source in (TIMESYNC, FILTER) and source != self.source
        self.source, self._other_since_ns = source, None

    # --- queries -------------------------------------------------------------------------------------

    def offset_ns(self, remote_us: int | None = None) -> int | None:
        """local - autopilot (ns) at remote_us (default: the newest sample), or None before any sample."""
        with self._lock:
            line = self._chosen()
            if line is None:
                return None
            return _at(line, line[0] if remote_us is None else int(remote_us) * 1000)

    def to_local_ns(self, remote_us: int, arrival_ns: int, stream=None) -> int:
        """Local time of a message stamped remote_us, never after its arrival and never before the stamp of an
        earlier-measured message of the same stream (an offset update must not put odometry out of order). Per
        stream: messages of different kinds carry different times of the same instant (PX4's HIGHRES_IMU
        time_usec is ahead of LOCAL_POSITION_NED's whole time_boot_ms), so one guard for all would skip."""
        with self._lock:
            return self._to_local_ns(remote_us, arrival_ns, stream)

    def _to_local_ns(self, remote_us, arrival_ns, stream):
        line = self._chosen()
        remote_ns = int(remote_us) * 1000
        local = arrival_ns if line is None else min(remote_ns + _at(line, remote_ns), arrival_ns)
        last_remote, last_local = self._last.get(stream, (-1, -1))
        if remote_us >= last_remote and local < last_local:
            local = min(last_local, arrival_ns)
        self._last[stream] = (int(remote_us), local)
        return local

    def drift_ppm(self) -> float:
        """The chosen line's drift: (our clock's rate / the autopilot's) - 1, in parts per million."""
        with self._lock:
            line = self._chosen()
            return math.nan if line is None else 1e6 * line[2]

    def jitter_ms(self) -> float:
        """Standard deviation of the chosen estimate's samples about its line: TIMESYNC's answers, or every
        message's arrival - time."""
        with self._lock:
            line = self._chosen()
            if line is None:
                return math.nan
            if self.source == 'timesync':
                samples = np.array([(r, off) for _, _, r, off in self._sync], dtype=np.int64)
            else:
                samples = np.array([(r, off) for _, r, off in self._oneway], dtype=np.int64)
        residuals = (samples[:, 1] - line[1]) - line[2] * (samples[:, 0] - line[0])
        return float(np.std(residuals) / 1e6) if len(residuals) > 1 else math.nan


def _at(line, remote_ns: int) -> int:
    r_ref, off_ref, drift = line[:3]
    return off_ref + int(round(drift * (remote_ns - r_ref)))


def answer_clock_ns() -> int:
    """The clock the bridge answers the vehicle's TIMESYNC requests with, and so the clock of the times it sends
    (an external pose's time_usec): the system clock, ROS time when use_sim_time is false. PX4 learns its offset to
    this clock from the answers (Timesync::update) and maps a companion's time_usec through it."""
    return time.time_ns()
