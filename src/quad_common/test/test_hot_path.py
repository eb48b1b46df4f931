"""HotPathExecutor: its pass over a ready subscription (one message, or its backlog up to takes_per_pass), its
slow pass (a probe that serves ready timers and hands anything else to the stock executor), and spin_once's wait."""

import contextlib
import math
import time

import pytest
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import UInt32

from quad_common.ros.hot_path import HotPathExecutor
from quad_common.ros.testing import TIMEOUT_S, isolated_domain

BACKLOG = 20


@contextlib.contextmanager
def _hot_node(name, hot, **executor_options):
    """(node, executor) on a context of their own in an isolated domain: hot(node) -> the hot subscriptions, served
    by a HotPathExecutor whose slow pass has already run once (with nothing queued)."""
    with isolated_domain() as (domain, _):
        ctx = rclpy.Context()
        rclpy.init(context=ctx, domain_id=domain)
        try:
            node = rclpy.create_node(name, context=ctx)
            subscriptions = []
            executor = HotPathExecutor(lambda: (subscriptions, []), context=ctx,
                                       **{'slow_period_s': 3600.0, **executor_options})
            executor.add_node(node)
            subscriptions += hot(node)
            executor.spin_once(timeout_sec=0.0)
            yield node, executor
            executor.shutdown()
            node.destroy_node()
        finally:
            rclpy.shutdown(context=ctx)


def _spin_until(executor, done, what):
    deadline = time.monotonic() + TIMEOUT_S
    while not done():
        assert time.monotonic() < deadline, what
        executor.spin_once(timeout_sec=0.01)


def _matched(executor, publishers):
    _spin_until(executor, lambda: all(pub.get_subscription_count() >= 1 for pub in publishers),
                'a subscription never matched its own node\'s publisher')


@pytest.mark.parametrize(('takes_per_pass', 'taken'), [(1, 1), (5, 5), (100, BACKLOG)])
def test_one_pass_takes_a_ready_subscriptions_backlog_up_to_takes_per_pass(takes_per_pass, taken):
    """BACKLOG messages queued (a publisher of the same node delivers within the process as it publishes); one
    wake-up of the hot path serves min(takes_per_pass, BACKLOG) of them, in order."""
    qos = QoSProfile(depth=BACKLOG, reliability=ReliabilityPolicy.RELIABLE)
    got = []
    with _hot_node('hot_path_backlog', lambda node: [node.create_subscription(
            UInt32, 'backlog', lambda msg: got.append(msg.data), qos)], takes_per_pass=takes_per_pass) as (node, ex):
        pub = node.create_publisher(UInt32, 'backlog', qos)
        _matched(ex, [pub])
        for k in range(BACKLOG):
            pub.publish(UInt32(data=k))
        ex.spin_once(timeout_sec=TIMEOUT_S)
        assert got == list(range(taken))


def test_one_pass_serves_the_ready_subscriptions_in_the_hot_lists_order():
    """Subscriptions ready at one wake-up are served in the order hot() lists them (a host lists /clock first:
    its ticks then see the new time), whatever order they were created or became ready in."""
    qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
    got = []

    def hot(node):
        subs = {name: node.create_subscription(UInt32, name, lambda msg, name=name: got.append(name), qos)
                for name in ('a', 'b', 'c', 'd')}
        return [subs[name] for name in ('c', 'a', 'd', 'b')]
    with _hot_node('hot_path_order', hot) as (node, ex):
        pubs = {name: node.create_publisher(UInt32, name, qos) for name in ('a', 'b', 'c', 'd')}
        _matched(ex, pubs.values())
        for name in ('a', 'b', 'd'):   # c is not ready: not served
            pubs[name].publish(UInt32(data=1))
        ex.spin_once(timeout_sec=TIMEOUT_S)
        assert got == ['a', 'd', 'b']


class _Host:
    """A node whose entities are all the slow pass's (no hot ones; slow_period_s 0: a slow pass each spin_once), and
    `stock`: how many times the stock executor's pass ran since its first."""

    def __init__(self, node, executor):
        self.node, self.executor, self.stock = node, executor, 0
        stock_pass = executor._spin_stock_ready

        def counted():
            self.stock += 1
            return stock_pass()
        executor._spin_stock_ready = counted

    def spin_until(self, done, what):
        _spin_until(self.executor, done, what)


@pytest.fixture
def host():
    with _hot_node('hot_path_slow', lambda node: [], slow_period_s=0.0) as (node, executor):
        yield _Host(node, executor)


def test_the_slow_pass_serves_ready_timers_without_the_stock_pass(host):
    """Between the stock executor's passes (one per STOCK_PERIOD_S) a ready timer of any node is served by the
    probe: its callback runs, the stock pass (a wait set over every entity) does not."""
    fired = []
    host.node.create_timer(0.001, lambda: fired.append(1))
    stock_before = host.stock
    host.spin_until(lambda: len(fired) >= 5, 'the timer never fired five times')
    assert host.stock == stock_before


def test_a_service_request_hands_the_slow_pass_to_the_stock_executor(host, monkeypatch):
    """Anything but a timer ready (here a service request) is served at once, by the stock pass, not at its
    next period."""
    from std_srvs.srv import Trigger

    monkeypatch.setattr(host.executor, '_next_stock_s', math.inf)   # no stock pass by its period in this test
    host.node.create_service(Trigger, 'probe_me', lambda request, response: setattr(response, 'success', True)
                             or response)
    client = host.node.create_client(Trigger, 'probe_me')
    host.executor.spin_once(timeout_sec=0.0)
    host.spin_until(client.service_is_ready, 'the service never matched')
    future = client.call_async(Trigger.Request())
    host.spin_until(future.done, 'the request was never served')
    assert future.result().success


def test_a_guard_condition_seen_by_the_probe_is_served(host):
    """rcl takes a guard condition's trigger in the wait that sees it: the probe triggers it again, so the stock
    pass it hands over to still serves it."""
    called = []
    guard = host.node.create_guard_condition(lambda: called.append(1))
    host.executor.spin_once(timeout_sec=0.0)
    stock_before = host.stock
    guard.trigger()
    host.spin_until(lambda: called, 'the guard condition\'s callback never ran')
    assert host.stock > stock_before


def test_the_stock_pass_still_runs_every_stock_period(host, monkeypatch):
    """The QoS event handlers are not in the probe: the stock pass serves them every STOCK_PERIOD_S."""
    from quad_common.ros import hot_path

    monkeypatch.setattr(hot_path, 'STOCK_PERIOD_S', 0.0)
    host.node.create_timer(3600.0, lambda: None)
    host.spin_until(lambda: host.stock >= 3, 'the stock pass stopped running')


def test_spin_once_does_not_wait_after_its_slow_turn_ran_a_callback():
    """A spin_once whose slow turn (hot passes, then the slow pass) already ran a callback returns without waiting:
    its caller looks first (a lockstep simulator's setpoints may all be in). Waiting here held the lockstep until the
    next message or the next slow pass (~0.1 s)."""
    qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
    got = []
    with _hot_node('hot_path_no_wait', lambda node: [node.create_subscription(
            UInt32, 'served', lambda msg: got.append(msg.data), qos)]) as (node, ex):
        pub = node.create_publisher(UInt32, 'served', qos)
        _matched(ex, [pub])
        waits = []
        spin_hot = ex._spin_hot
        ex._spin_hot = lambda wait_s: waits.append(wait_s) or spin_hot(wait_s)
        pub.publish(UInt32(data=7))
        ex._next_slow_s = 0.0   # this spin_once is the slow pass's turn
        ex.spin_once(timeout_sec=TIMEOUT_S)
        assert got == [7]
        assert waits and max(waits) == 0.0
