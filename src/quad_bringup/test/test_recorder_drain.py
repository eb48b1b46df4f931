"""recorder_node.drain and record on a simulated clock: when the drain ends, given what arrives after the stop;
how many wake-ups the recording takes a lockstep's bursts in."""

from types import SimpleNamespace

import pytest

from quad_bringup.recording import recorder_node


class _Graph:
    """A clock that each spin advances by its timeout, and messages that arrive at given times: (arrival s, sent
    before the stop)."""

    def __init__(self, arrivals, publishers_gone_s=float('inf')):
        self.now_s, self.arrivals = 0.0, sorted(arrivals)
        self.node = SimpleNamespace(stop_ns=None, sent_before_stop=0, bag=SimpleNamespace(total=0),
                                    publishers_left=lambda: self.now_s < publishers_gone_s,
                                    _raw_subscriptions={'/odom': self})
        self.handle, self.msg_type = self, None   # the one subscription: recorder_node.take_ready takes from it

    def monotonic(self):
        return self.now_s

    def spin_once(self, timeout_sec):
        """Takes one message that has arrived (as a pass takes one per subscription)."""
        self.now_s += timeout_sec
        message = self.take_message(None, True)
        if message is not None:
            self.callback(*message)

    def take_message(self, msg_type, raw):
        if self.arrivals and self.arrivals[0][0] <= self.now_s:
            return self.arrivals.pop(0)[1:]
        return None

    def callback(self, before_stop):
        self.node.sent_before_stop += before_stop
        self.node.bag.total += 1

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def _drain(monkeypatch, arrivals, pass_s=0.2, publishers_gone_s=float('inf')):
    graph = _Graph(arrivals, publishers_gone_s)
    monkeypatch.setattr(recorder_node.time, 'monotonic', graph.monotonic)
    recorder_node.drain(graph.node, graph, pass_s)
    return graph


def test_the_drain_ends_pass_s_after_the_last_message_sent_before_the_stop(monkeypatch):
    graph = _drain(monkeypatch, [(0.03, True), (0.05, True), (0.12, True)])
    assert graph.node.sent_before_stop == 3 and not graph.arrivals
    assert graph.now_s == pytest.approx(0.12 + 0.2, abs=0.011)   # one quiet pass_s after the last: not two passes


def test_with_nothing_left_the_drain_is_one_quiet_pass(monkeypatch):
    assert _drain(monkeypatch, []).now_s == pytest.approx(0.2, abs=0.011)


def test_messages_sent_after_the_stop_do_not_prolong_the_drain(monkeypatch):
    graph = _drain(monkeypatch, [(0.01 * k, False) for k in range(1, 100)])   # a publisher that never stops
    assert graph.node.sent_before_stop == 0
    assert graph.now_s == pytest.approx(0.2, abs=0.011)


def test_with_every_publisher_gone_the_drain_takes_what_is_there_and_ends(monkeypatch):
    graph = _drain(monkeypatch, [(0.01, True)] + [(0.05, True)] * 3, publishers_gone_s=0.05)
    assert graph.node.sent_before_stop == 4 and not graph.arrivals   # all taken, three after they left
    assert graph.now_s == pytest.approx(0.05, abs=0.011)              # not a quiet pass_s more


class _Bursts:
    """Messages arriving at given times: a spin waits for the first (up to its timeout) and takes every one arrived
    by then (a pass takes each ready subscription's backlog); a sleep advances the clock; the stop comes once all
    are taken."""

    def __init__(self, arrivals_s, take_pause_s):
        self.now_s, self.arrivals, self.wakeups, self.latest_s, self.stop = 0.0, sorted(arrivals_s), 0, 0.0, []
        self.node = SimpleNamespace(params={'take_pause_s': take_pause_s}, bag=SimpleNamespace(total=0))

    def spin_once(self, timeout_sec):
        if not self.arrivals:
            self.stop.append('SIGTERM')
            return
        self.now_s = max(self.now_s, min(self.arrivals[0], self.now_s + timeout_sec))
        taken = [t for t in self.arrivals if t <= self.now_s]
        if taken:
            self.wakeups += 1
            self.latest_s = max(self.latest_s, self.now_s - taken[0])
            self.arrivals = self.arrivals[len(taken):]
            self.node.bag.total += len(taken)

    def sleep(self, seconds):
        self.now_s += seconds


def _record(take_pause_s, steps=20, step_s=0.003, per_step=33, spread_s=0.0016):
    """A 16-vehicle lockstep: per step_s, /clock and the odometry at once, the setpoints one by one over spread_s."""
    arrivals = [k * step_s + (0.0 if m <= 16 else spread_s * (m - 16) / (per_step - 17))
                for k in range(steps) for m in range(per_step)]
    graph = _Bursts(arrivals, take_pause_s)
    recorder_node.record(graph.node, graph, graph.stop, sleep=graph.sleep)
    assert graph.node.bag.total == steps * per_step and graph.stop
    return graph


def test_the_recording_takes_a_steps_burst_in_one_wake_up_no_later_than_its_pause():
    graph = _record(0.005)
    assert graph.wakeups <= 20          # one per message (17 a step) without the pause
    assert graph.latest_s <= 0.005 + 0.003


def test_with_no_pause_every_message_is_taken_as_it_arrives():
    graph = _record(0.0)
    assert graph.latest_s == 0.0 and graph.wakeups == 20 * 17
