"""Telemetry clock mapping, stream fall-backs, the event-driven setpoint streamer and the clamp that keeps the
vertical acceleration."""

import math
import threading

import numpy as np
import pytest

from quad_bridge.backend import StreamGroup
from quad_bridge.clock import SWITCH_PERSIST_S, ClockMapper
from quad_bridge.setpoint import check_setpoint
from quad_bridge.setpoint_stream import SetpointStreamer
from quad_bridge.telemetry_streams import StreamSelector
from quad_common import rotations
from quad_common.types import AttitudeSetpoint

MS = 1_000_000


def test_burst_arrivals_are_stamped_with_the_autopilot_time():
    """Messages every 20 ms of autopilot time arriving in bursts of three (delays 5..45 ms) keep 20 ms spacing."""
    clock = ClockMapper()
    offset = 1_000_000 * MS
    stamps = []
    for k in range(60):
        remote_us = 20_000 * k
        arrival = offset + remote_us * 1000 + (5 + 20 * (2 - k % 3)) * MS   # released together every third
        clock.observe(remote_us, arrival)
        stamps.append(clock.to_local_ns(remote_us, arrival))
    gaps = [(b - a) / MS for a, b in zip(stamps[10:], stamps[11:])]
    assert all(g == pytest.approx(20.0, abs=1e-6) for g in gaps)
    assert clock.source == 'arrival minimum filter' and clock.jitter_ms() > 10.0
    assert all(s <= offset + 20_000_000 * k + 45 * MS for k, s in enumerate(stamps))   # never after arrival


def test_timesync_is_used_while_it_agrees_and_dropped_when_it_does_not():
    clock = ClockMapper()
    offset = 500 * MS
    for k in range(20):
        clock.observe(20_000 * k, offset + 20_000_000 * k + 2 * MS)
    clock.timesync(ts1_local_ns=offset + 100 * MS, tc1_remote_ns=100 * MS + MS // 2, reply_local_ns=offset + 101 * MS)
    assert clock.offset_ns() == offset and clock.source == 'timesync'
    wrong = ClockMapper()
    for k in range(20):
        wrong.observe(20_000 * k, offset + 20_000_000 * k + 2 * MS)
    wrong.timesync(0, 10_000 * MS, MS)   # a TIMESYNC clock unrelated to the message times (seconds off)
    assert wrong.offset_ns() == offset + 2 * MS and wrong.source == 'arrival minimum filter'


def test_stream_fall_back_and_missing_report():
    groups = (StreamGroup('imu', (('HIGHRES_IMU',), ('SCALED_IMU',))),
              StreamGroup('odometry', (('LOCAL_POSITION_NED', 'ATTITUDE_QUATERNION'), ('ODOMETRY',))))
    sel = StreamSelector(groups, grace_s=3.0)
    sel.reset(0.0)
    sel.arrived('LOCAL_POSITION_NED', 0.5)
    sel.arrived('ATTITUDE_QUATERNION', 0.5)
    sel.arrived('ODOMETRY', 0.5)                   # sent unasked: not used while the first set arrives
    assert sel.update(1.0) == [] and sel.uses('odometry', 'LOCAL_POSITION_NED') and not sel.uses('odometry', 'ODOMETRY')
    assert sel.update(3.5) == [('imu', ('SCALED_IMU',))] and 'HIGHRES_IMU never arrived' in sel.notes[0]
    assert sel.missing(4.0) == []
    assert sel.missing(6.6) == ['SCALED_IMU']      # the fall-back never came either: reported
    assert sel.update(7.0) == []                   # nothing left to fall back to


class FakeClock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def test_a_new_setpoint_goes_out_at_once_and_the_keep_alive_only_fills_gaps():
    clock, sent, quiet = FakeClock(), [], []
    allowed = threading.Event()
    s = SetpointStreamer(sent.append, allowed.is_set, rate_hz=50.0, timeout_s=0.5,
                         on_stale=lambda *a: quiet.append(a), clock=clock)
    s.submit('a')
    assert sent == []                              # no hand-over: nothing on the wire
    allowed.set()
    for k in range(5):                             # 200 Hz input: each one sent on arrival, none lost
        clock.t = 0.005 * k
        s.submit(k)
        assert s._tick() > 0
    assert sent == [0, 1, 2, 3, 4] and s.superseded == 1 and s.keepalives == 0
    clock.t = 0.02 + 0.029                         # not yet: a late setpoint at the keep-alive's rate is no gap
    s._tick()
    assert s.keepalives == 0
    clock.t = 0.02 + 0.031                         # 1.5 periods without a new one: the keep-alive re-sends
    s._tick()
    assert sent[-1] == 4 and s.keepalives == 1
    clock.t = 0.051 + 0.021                        # then every period
    s._tick()
    assert s.keepalives == 2
    clock.t = 0.8                                  # input stale: no re-send of an old setpoint, reported once
    s._tick()
    s._tick()
    assert s.keepalives == 2 and len(quiet) == 1 and quiet[0][1] > 0.5


def _stream(streamer, clock, arrivals_s, until_s):
    """The setpoint thread's loop on a fake clock: wakes at the next setpoint or at the keep-alive's deadline,
    whichever comes first. Returns the wake-ups."""
    arrivals, wakes, deadline = sorted(arrivals_s), 0, 0.0
    while clock.t < until_s:
        clock.t = min(arrivals[0], deadline) if arrivals else deadline
        wakes += 1
        if arrivals and arrivals[0] <= clock.t:
            streamer.submit(arrivals.pop(0))
        deadline = clock.t + streamer.tick()
    return wakes


def test_a_controller_at_the_keep_alive_rate_puts_each_setpoint_on_the_wire_once():
    """A 50 Hz controller whose setpoints arrive up to 0.4 of a period late (a busy machine's jitter) against the
    50 Hz keep-alive: no re-sends in between, one send and one wake-up per setpoint (a keep-alive due
    after one period would re-send just before the next setpoint, doubling datagrams and wake-ups)."""
    rng = np.random.default_rng(7)
    clock, sent = FakeClock(), []
    s = SetpointStreamer(sent.append, lambda: True, 50.0, 0.5, lambda *a: None, clock=clock)
    arrivals = [0.02 * k + 0.008 * rng.random() for k in range(500)]
    wakes = _stream(s, clock, arrivals, until_s=arrivals[-1])
    assert s.keepalives == 0 and len(sent) == 500 and wakes <= 500 + 1


def test_a_stream_that_stops_is_kept_alive_with_gaps_no_longer_than_one_and_a_half_periods():
    clock, sent_at = FakeClock(), []
    s = SetpointStreamer(lambda sp: sent_at.append(clock.t), lambda: True, 50.0, 0.5, lambda *a: None, clock=clock)
    _stream(s, clock, [0.02 * k for k in range(10)], until_s=0.45)
    gaps = np.diff(sent_at)
    assert s.keepalives >= 10 and gaps.max() <= s.max_wire_gap_s() + 1e-9 and s.max_wire_gap_s() == pytest.approx(0.03)
    assert gaps[9] == pytest.approx(0.03) and np.allclose(gaps[10:], 0.02)   # the first re-send, then each period


def test_setpoints_that_stop_are_stale_setpoint_timeout_s_after_the_last_one():
    """The controller stops at 1.0 s: the keep-alive re-sends the last setpoint, and the stale report comes when
    that setpoint is timeout_s old (1.5 s), not when the wire has been quiet for timeout_s after the last
    re-send (2.0 s, as PX4 SIH showed: 2 x setpoint_timeout_s); the keep-alive's own wait wakes it in time."""
    clock, quiet = FakeClock(), []
    s = SetpointStreamer(lambda sp: None, lambda: True, 50.0, 0.5, lambda *a: quiet.append((clock.t, *a)),
                         clock=clock)
    for k in range(51):
        clock.t = 0.02 * k
        s.submit(k)
    while not quiet and clock.t < 3.0:
        clock.t += min(s._tick(), 0.05)
    at, wire_age, input_age = quiet[0]
    assert 1.5 < at <= 1.5 + 0.002 and wire_age < 0.05 and input_age > 0.5
    assert s.keepalives >= 20


def test_a_stopped_hand_over_with_fresh_input_is_reported_as_a_quiet_wire():
    clock, quiet = FakeClock(), []
    allowed = threading.Event()
    allowed.set()
    s = SetpointStreamer(lambda sp: None, allowed.is_set, 50.0, 0.5, lambda *a: quiet.append(a), clock=clock)
    s.submit('x')
    allowed.clear()                                # e.g. the pilot switched mode
    for k in range(1, 40):
        clock.t = 0.02 * k
        s.submit('x')
        s._tick()
    assert len(quiet) == 1 and quiet[0][1] < 0.5   # wire quiet, input fresh


@pytest.mark.parametrize('tilt_deg, f, expected_f', [
    (60.0, 2 * 9.81, 9.81 / math.cos(math.radians(35.0))),   # level flight at 60 deg -> level at 35 deg
    (45.0, 9.81, 9.81 * math.cos(math.radians(45.0)) / math.cos(math.radians(35.0))),
])
def test_the_clamp_keeps_the_vertical_acceleration(tilt_deg, f, expected_f):
    q = rotations.from_euler(math.radians(tilt_deg), 0.0, 0.0)
    sp, clamped, kept = check_setpoint(AttitudeSetpoint(quaternion=q, specific_force_mps2=f), math.radians(35.0))
    assert clamped and kept and sp.specific_force_mps2 == pytest.approx(expected_f)
    vertical = sp.specific_force_mps2 * rotations.to_matrix(sp.quaternion)[2, 2]
    assert vertical == pytest.approx(f * math.cos(math.radians(tilt_deg)))


def test_the_clamp_says_when_the_thrust_limit_cuts_the_vertical_acceleration():
    q = rotations.from_euler(math.radians(70.0), 0.0, 0.0)
    sp, clamped, kept = check_setpoint(AttitudeSetpoint(quaternion=q, specific_force_mps2=60.0),
                                       math.radians(35.0), max_specific_force_mps2=19.62)
    assert clamped and not kept and sp.specific_force_mps2 == 19.62


def test_stamps_never_go_back_when_the_offset_estimate_improves():
    """The filter's offset (50 ms of delay in it) gives way to TIMESYNC's (1 ms): the next stamp may not jump back."""
    clock = ClockMapper()
    clock.observe(0, 50 * MS)
    first = clock.to_local_ns(20_000, 75 * MS)      # 20 + 50 = 70 ms
    clock.timesync(ts1_local_ns=80 * MS, tc1_remote_ns=79 * MS, reply_local_ns=80 * MS)   # offset 1 ms
    second = clock.to_local_ns(40_000, 95 * MS)     # 40 + 1 = 41 ms < 70 ms
    assert clock.source == 'timesync' and first == 70 * MS and second == first
    assert clock.to_local_ns(120_000, 125 * MS) == 121 * MS   # and later ones follow the better offset


def test_a_stream_never_goes_back_when_another_stream_is_mapped_ahead_of_it():
    """PX4 sends HIGHRES_IMU (time_usec) just ahead of LOCAL_POSITION_NED (whole ms) of the same instant. With
    one guard for all streams, the position after an IMU message was not guarded and its stamp went back when
    the offset dropped (seen at 5 ms under load); each stream keeps its own order."""
    clock = ClockMapper()
    clock.observe(0, 50 * MS)                                      # offset 50 ms
    first = clock.to_local_ns(20_000, 75 * MS, 'LOCAL_POSITION_NED')       # 70 ms
    clock.timesync(ts1_local_ns=80 * MS, tc1_remote_ns=79 * MS, reply_local_ns=80 * MS)   # offset 1 ms
    clock.to_local_ns(40_400, 95 * MS, 'HIGHRES_IMU')              # the IMU of the next instant, 0.4 ms ahead
    second = clock.to_local_ns(40_000, 95 * MS, 'LOCAL_POSITION_NED')      # 41 ms < 70 ms: held at 70
    assert second == first


def _drifting_link(rate, seconds, latency_ms=20.0, timesync=True, stall_at_s=None, seed=1, reply_ms=(0.5, 3.0)):
    """A 50 Hz stream from an autopilot whose clock runs at `rate` of ours (offset 3 s at our t = 0), each message
    latency_ms + up to 2 ms late (a 0.5 s stall holds everything from stall_at_s), and a TIMESYNC every second
    (the request up to reply_ms late at the autopilot, the reply 0.5-1 ms: asymmetric); returns (clock, [(remote
    us, stamp ns, truth ns)])."""
    import random
    rng = random.Random(seed)
    clock, out = ClockMapper(), []
    origin = 10**18
    for k in range(int(seconds * 50)):
        t_ns = origin + k * 20 * MS                         # our time of the measurement (the truth)
        remote_us = int((3e9 + rate * (t_ns - origin)) / 1000)
        delay = latency_ms * MS + rng.uniform(0, 2) * MS
        if stall_at_s is not None and stall_at_s <= k / 50 < stall_at_s + 0.5:
            delay += (stall_at_s + 0.5 - k / 50) * 1e9
        arrival = t_ns + int(delay)
        clock.observe(remote_us, arrival)
        out.append((remote_us, clock.to_local_ns(remote_us, arrival), t_ns))
        if timesync and k % 50 == 25:
            up, down = rng.uniform(*reply_ms) * MS, rng.uniform(0.5, 1) * MS
            tc1 = int(3e9 + rate * (t_ns + up - origin))
            clock.timesync(t_ns, tc1, int(t_ns + up + down))
    return clock, out


@pytest.mark.parametrize('rate', [0.985, 0.93, 1.00005])
def test_a_drifting_autopilot_clock_is_followed_with_timesync(rate):
    """PX4 SIH's clock ran at 0.984-0.993 of ours (0.93 under load), a crystal drifts by tens of ppm: after the fit
    has 2 s, every stamp within 3 ms of the truth (the old window minimum: up to drift x 10 s early)."""
    clock, out = _drifting_link(rate, 20.0)
    errors = [(stamp - truth) / MS for remote, stamp, truth in out[150:]]
    assert clock.source == 'timesync'
    assert clock.drift_ppm() == pytest.approx(1e6 * (1 / rate - 1), abs=100.0)
    assert max(abs(e) for e in errors) < 3.0, (min(errors), max(errors))


def test_without_timesync_the_filter_follows_the_drift_a_latency_late_through_a_stall():
    """No TIMESYNC: the filter's line is the smallest delay late (20 ms), never early, and half a second in which
    every message was held back (a stalled link) does not move it."""
    clock, out = _drifting_link(0.985, 20.0, timesync=False, stall_at_s=12.0)
    errors = [(stamp - truth) / MS for remote, stamp, truth in out[150:] if not 12.0 <= (truth - 10**18) / 1e9 < 13.0]
    assert clock.source == 'arrival minimum filter'
    assert all(19.0 < e < 23.0 for e in errors), (min(errors), max(errors))


def test_timesync_answered_late_on_a_loaded_machine_does_not_invent_a_drift():
    """A clock without drift whose TIMESYNC answers come 100-400 ms late and uneven (a starved autopilot process):
    a line through them alone said +21000 ppm (seen under load 10); the drift is taken from the estimate that
    knows it better, the message times' minima (their offset stays ambiguous: answers that late and uneven cannot
    say whether the request or the reply was slow)."""
    for seed in (1, 2, 3):   # a line through TIMESYNC alone: -289, -2978, 9 ppm
        clock, _ = _drifting_link(1.0, 20.0, reply_ms=(100.0, 400.0), seed=seed)
        assert abs(clock.drift_ppm()) < 100.0, seed


def _sources_over_a_link(seconds, asymmetry_ms, seed=1, rate=0.992):
    """A 50 Hz stream 0.2 ms + an exponential 1 ms late and a TIMESYNC every second whose reply is asymmetry_ms(t_s)
    +- 0.25 ms slower than its request (TIMESYNC's offset is half that off); returns (clock, the source after each
    message, [(t_s, stamp error ms)])."""
    import random
    rng = random.Random(seed)
    clock, sources, errors = ClockMapper(), [], []
    origin = 10**18
    for k in range(int(seconds * 50)):
        t_ns = origin + k * 20 * MS
        remote_us = int((3e9 + rate * (t_ns - origin)) / 1000)
        arrival = t_ns + int(0.2 * MS + rng.expovariate(1.0) * MS)
        clock.observe(remote_us, arrival)
        errors.append((k / 50, (clock.to_local_ns(remote_us, arrival) - t_ns) / MS))
        sources.append(clock.source)
        if k % 50 == 25:
            up = rng.uniform(0.2, 1.0) * MS
            down = up + (asymmetry_ms(k / 50) + rng.uniform(-0.25, 0.25)) * MS
            clock.timesync(t_ns, int(3e9 + rate * (t_ns + up - origin)), int(t_ns + up + down))
    return clock, sources, errors


def _flips(sources):
    return sum(a != b for a, b in zip(sources, sources[1:]))


@pytest.mark.parametrize('seed', [1, 2, 3])
def test_the_clock_source_does_not_flip_while_timesync_sits_at_its_bound(seed):
    """TIMESYNC's stamps about 1 ms after the earliest arrivals, just at the bound that admits it (PX4 SIH: the
    source alternated 11-17 times a flight; this link flipped 129-174 times in 2 minutes without hysteresis): one
    switch, the first filter -> TIMESYNC, and the stamps within 2 ms of the truth."""
    clock, sources, errors = _sources_over_a_link(120.0, lambda t_s: 2.8, seed)
    assert _flips(sources) <= 1 and clock.switches <= 1, _flips(sources)
    assert max(abs(e) for t_s, e in errors if t_s > 5.0) < 2.0


def test_a_persistent_disagreement_still_switches_and_a_gross_one_at_once():
    """TIMESYNC agrees for 30 s, then its stamps lie 2.8 ms after the arrivals for good: the filter takes over (once
    the window's better answers aged out and SWITCH_PERSIST_S passed) and stays. A TIMESYNC seconds off (an
    unrelated clock) is dropped at once."""
    clock, sources, _ = _sources_over_a_link(60.0, lambda t_s: 1.0 if t_s < 30.0 else 6.0)
    assert sources[1400] == 'timesync' and sources[-1] == 'arrival minimum filter'
    assert _flips(sources[1400:]) == 1
    switched_s = sources[1400:].index('arrival minimum filter') / 50 + 28.0
    assert switched_s < 30.0 + 10.0 + SWITCH_PERSIST_S + 1.0, switched_s
    clock, sources, _ = _sources_over_a_link(10.0, lambda t_s: 1.0)
    assert clock.source == 'timesync'
    clock.timesync(10**18 + 10 * 10**9, 10**6, 10**18 + 10 * 10**9 + MS)   # an unrelated clock: at once
    assert clock.offset_ns() is not None and clock.source == 'arrival minimum filter'


def test_the_clock_line_on_python_numbers_is_numpys_least_squares():
    """clock._line (on Python numbers) against numpy's least squares on the same points: offset,
    drift, residuals and standard error; too few points or too short a span give drift 0 as before."""

    from quad_bridge import clock as clk

    rng = np.random.default_rng(5)
    for drift in (0.0, 1e-4, -0.02, 0.15):
        remote = np.cumsum(rng.integers(200_000_000, 300_000_000, size=40)) + 10**12
        offset = (10**15 + drift * (remote - remote[-1]) + rng.exponential(3e5, size=40)).astype(np.int64)
        r_ref, off_ref, d, residuals, se = clk._line(remote.tolist(), offset.tolist())
        x, y = (remote - remote[-1]) / 1e9, (offset - offset.min()).astype(float)
        slope, intercept = np.polyfit(x, y, 1)
        expected_residuals = y - (intercept + slope * x)
        assert r_ref == remote[-1] and off_ref == offset.min() + int(round(intercept))
        assert d == pytest.approx(slope / 1e9, rel=1e-9, abs=1e-15)
        np.testing.assert_allclose(residuals, expected_residuals, atol=1e-3)
        assert se == pytest.approx(np.sqrt(expected_residuals @ expected_residuals / 38 / ((x - x.mean()) ** 2).sum())
                                   / 1e9, rel=1e-6)
    few = clk._line([10**9, 2 * 10**9], [5, 7])
    assert few[2] == 0.0 and few[4] == math.inf and few[1] == 5


def test_after_a_stall_every_queued_setpoint_is_taken_oldest_first_and_the_newest_goes_out_last():
    """SetpointPath._take_all on a backlog (the setpoint thread held while the controller kept publishing): each
    queued setpoint is handled in order, a refused publisher's skipped, and the newest is the last on the wire and
    the one the keep-alive re-sends."""
    from quad_bridge.setpoint_path import SetpointPath

    clock, sent = FakeClock(), []
    streamer = SetpointStreamer(sent.append, lambda: True, 50.0, 0.5, lambda *a: None, clock=clock)
    queue = [(True, 1), (True, None), (True, 2), (True, 3), (False, None)]   # None: a refused publisher's

    class Path:
        def _take(self, sub):
            return queue.pop(0)

        def on_setpoint(self, raw):
            streamer.submit(raw)

    SetpointPath._take_all(Path(), sub=None)
    assert sent == [1, 2, 3] and not queue
    clock.t += 0.031
    streamer.tick()
    assert sent[-1] == 3 and streamer.keepalives == 1


def test_the_setpoint_thread_ends_quietly_when_ctrl_c_shut_rclpy_down_before_it_began():
    """A second Ctrl-C during start-up can shut the context down before the setpoint thread makes its wait set:
    the thread ends without a traceback."""
    import threading

    import rclpy
    from rclpy.context import Context

    from quad_bridge.setpoint_path import SetpointPath

    context = Context()
    rclpy.init(context=context)
    rclpy.shutdown(context=context)

    class Path:
        bridge = type('Bridge', (), {'context': context})()
        sub = streamer = None
        stopping = threading.Event()

    SetpointPath._spin(Path())   # returns: no wait set on a shut context, and no exception
