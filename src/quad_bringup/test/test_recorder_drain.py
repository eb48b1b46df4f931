"""recorder_node.drain on a simulated clock: when it ends, given what arrives after the stop."""

from types import SimpleNamespace

import pytest

from quad_bringup.recording import recorder_node


class _Graph:
    """A clock that each spin advances by its timeout, and messages that arrive at given times: (arrival s, sent
    before the stop)."""

    def __init__(self, arrivals, publishers_gone_s=float('inf')):
        self.now_s, self.arrivals = 0.0, sorted(arrivals)
        self.node = SimpleNamespace(stop_ns=None, sent_before_stop=0, bag=SimpleNamespace(total=0),
                                    publishers_left=lambda: self.now_s < publishers_gone_s)

    def monotonic(self):
        return self.now_s

    def spin_once(self, timeout_sec):
        """Takes one message that has arrived (as a pass takes one per subscription)."""
        self.now_s += timeout_sec
        if self.arrivals and self.arrivals[0][0] <= self.now_s:
            _, before_stop = self.arrivals.pop(0)
            self.node.sent_before_stop += before_stop
            self.node.bag.total += 1


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
