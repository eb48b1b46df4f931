"""The setpoint path: a new setpoint goes on the wire at once; a keep-alive re-sends the newest one
only when none went out for a whole period (the stream autopilots need to stay in offboard), and watches for a
stale stream. No rclpy: the caller hands in what to send and whether it may.

    submit(sp) -> [may_send?] -> send(sp)                  (the subscriber's thread, no waiting)
    keep-alive: 1.5 periods without a new one, then every period -> send(newest); nothing sent for
                timeout_s -> on_stale()

The keep-alive runs in a thread of its own (start()), or, with `wake`, in the owner's thread: the owner calls
tick() when the delay tick() last returned has passed (mavlink_bridge: the setpoint thread, whose wait for the
next setpoint is bounded by it, so a setpoint stream at the keep-alive rate wakes one thread, not two).
"""

import math
import threading
import time

from quad_bridge.link import RateMeter

MIN_WAIT_S = 0.0005   # the keep-alive's shortest wait
# After a new setpoint the keep-alive waits this many periods before its first re-send, then one period each: a
# controller publishing at the keep-alive's own rate arrives up to this late without a re-send. At 1.0 the jitter
# of a 50 Hz controller against a 50 Hz keep-alive put a re-send just before the next setpoint on 0-22 % of the
# setpoints (bench_bridge_telemetry: a second datagram and a second wake-up each). The wire's longest gap while
# the input is fresh is therefore FIRST_RESEND_PERIODS / rate (what the autopilot's loss timeout must exceed).
FIRST_RESEND_PERIODS = 1.5


class SetpointStreamer:
    def __init__(self, send, may_send, rate_hz: float, timeout_s: float, on_stale, on_error=None,
                 clock=time.monotonic, wake=None):
        """send(sp): puts one setpoint on the wire; may_send() -> bool: the hand-over allows it now;
        on_stale(wire_age_s, input_age_s): nothing went out for timeout_s after a send (called once per quiet
        spell); input_age_s > timeout_s says the setpoints themselves stopped. wake(): wakes the owner's thread
        to call tick() now (the owner runs the keep-alive; start() then starts no thread)."""
        self._send, self._may_send, self._on_stale, self._on_error = send, may_send, on_stale, on_error
        self.period_s, self.timeout_s, self.clock = 1.0 / rate_hz, timeout_s, clock
        self.lock = threading.Lock()  # one sender at a time, and the fields below
        self.setpoint = None
        self.received_s = -math.inf   # when the newest setpoint arrived
        self.sent_s = -math.inf       # when the last one went out
        self.reported_sent_s = -math.inf  # the last send whose silence was reported
        self.sent = RateMeter()
        self.received = self.sent_total = self.superseded = self.keepalives = 0
        self._unsent = False          # the newest setpoint has not been on the wire
        self._resent = False          # the last send was the keep-alive's (the next one is due a period after it)
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._owner_wake = wake
        self._thread = None if wake else threading.Thread(target=self._run, name='setpoint-keepalive', daemon=True)

    def start(self):
        if self._thread:
            self._thread.start()

    def stop(self):
        self._stop.set()
        self._wake.set()
        if self._thread:
            self._thread.join(timeout=2.0)

    def fresh(self, now_s=None) -> bool:
        now_s = self.clock() if now_s is None else now_s
        return self.setpoint is not None and now_s - self.received_s <= self.timeout_s

    def submit(self, sp):
        """A new valid setpoint: on the wire now if the hand-over allows it."""
        with self.lock:
            now = self.clock()
            self.received += 1
            if self._unsent:
                self.superseded += 1
            self.setpoint, self.received_s, self._unsent = sp, now, True
            if self._may_send():
                self._emit(now)

    def kick(self):
        """The hand-over began: send the newest fresh setpoint now and keep the stream alive from here."""
        with self.lock:
            if self.fresh() and self._may_send():
                self._emit(self.clock())
        if self._owner_wake:
            self._owner_wake()
        else:
            self._wake.set()

    def max_wire_gap_s(self) -> float:
        """The longest the wire stays quiet while the input is fresh: the first re-send's wait."""
        return FIRST_RESEND_PERIODS * self.period_s

    def _emit(self, now, resend=False):
        self._send(self.setpoint)
        self.sent_s, self._unsent, self._resent = now, False, resend
        self.sent_total += 1
        self.sent.tick(now)

    def rate_hz(self) -> float:
        with self.lock:
            return self.sent.rate_hz(self.clock())

    def _run(self):
        while not self._stop.is_set():
            self._wake.wait(self.tick())
            self._wake.clear()

    def tick(self) -> float:
        """The keep-alive's work now (_tick); returns the seconds until it is due again (>= MIN_WAIT_S). Never
        raises: an error goes to on_error (the keep-alive must not die silently)."""
        try:
            delay_s = self._tick()
        except Exception as exc:
            if self._on_error:
                self._on_error(exc)
            delay_s = self.period_s
        return max(delay_s, MIN_WAIT_S)

    def _tick(self) -> float:
        """Re-send when FIRST_RESEND_PERIODS passed after a new setpoint's send, then every period; report once
        when the setpoints stopped for timeout_s, or the wire went quiet for timeout_s (the vehicle keeps flying
        the last setpoint meanwhile). The setpoints' own age decides, not the wire's: the keep-alive re-sends the
        last one until it is timeout_s old, and waiting for the wire to go quiet after that takes 2 x timeout_s.
        Returns the next wait."""
        report = None
        with self.lock:
            now = self.clock()
            input_age = now - self.received_s
            due_s = self.sent_s + (self.period_s if self._resent else self.max_wire_gap_s())
            if input_age <= self.timeout_s and now >= due_s and self._may_send():
                self._emit(now, resend=True)
                self.keepalives += 1
                due_s = now + self.period_s
            wire_age = now - self.sent_s
            if (wire_age > self.timeout_s or input_age > self.timeout_s) and self.sent_s > self.reported_sent_s:
                self.reported_sent_s, report = self.sent_s, (wire_age, input_age)
            next_send = due_s - now
            next_quiet = (min(self.sent_s, self.received_s) + self.timeout_s - now
                          if self.sent_s > self.reported_sent_s else self.period_s)
        if report is not None:
            self._on_stale(*report)
        return min(next_send if next_send > 0 else self.period_s, next_quiet + 1e-4, self.max_wire_gap_s())
