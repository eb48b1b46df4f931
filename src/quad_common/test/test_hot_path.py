"""HotPathExecutor's pass over a ready subscription: one message, or its backlog up to takes_per_pass."""

import time

import pytest
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import UInt32

from quad_common.ros.hot_path import HotPathExecutor
from quad_common.ros.testing import TIMEOUT_S, isolated_domain

BACKLOG = 20


@pytest.mark.parametrize(('takes_per_pass', 'taken'), [(1, 1), (5, 5), (100, BACKLOG)])
def test_one_pass_takes_a_ready_subscriptions_backlog_up_to_takes_per_pass(takes_per_pass, taken):
    """BACKLOG messages queued (a publisher of the same node delivers within the process as it publishes); one
    wake-up of the hot path serves min(takes_per_pass, BACKLOG) of them, in order."""
    with isolated_domain() as (domain, _):
        ctx = rclpy.Context()
        rclpy.init(context=ctx, domain_id=domain)
        try:
            node = rclpy.create_node('hot_path_backlog', context=ctx)
            qos = QoSProfile(depth=BACKLOG, reliability=ReliabilityPolicy.RELIABLE)
            got = []
            sub = node.create_subscription(UInt32, 'backlog', lambda msg: got.append(msg.data), qos)
            pub = node.create_publisher(UInt32, 'backlog', qos)
            executor = HotPathExecutor(lambda: ([sub], []), slow_period_s=3600.0, context=ctx,
                                       takes_per_pass=takes_per_pass)
            executor.add_node(node)
            executor.spin_once(timeout_sec=0.0)   # its first slow pass, with nothing queued yet
            deadline = time.monotonic() + TIMEOUT_S
            while pub.get_subscription_count() < 1:
                assert time.monotonic() < deadline, 'the subscription never matched its own node\'s publisher'
                executor.spin_once(timeout_sec=0.01)
            for k in range(BACKLOG):
                pub.publish(UInt32(data=k))
            executor.spin_once(timeout_sec=TIMEOUT_S)
            assert got == list(range(taken))
            executor.shutdown()
            node.destroy_node()
        finally:
            rclpy.shutdown(context=ctx)


def test_one_pass_serves_the_ready_subscriptions_in_the_hot_lists_order():
    """Subscriptions ready at one wake-up are served in the order hot() lists them (a host lists /clock first:
    its ticks then see the new time), whatever order they were created or became ready in."""
    with isolated_domain() as (domain, _):
        ctx = rclpy.Context()
        rclpy.init(context=ctx, domain_id=domain)
        try:
            node = rclpy.create_node('hot_path_order', context=ctx)
            qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
            got = []
            subs = {name: node.create_subscription(UInt32, name, lambda msg, name=name: got.append(name), qos)
                    for name in ('a', 'b', 'c', 'd')}
            pubs = {name: node.create_publisher(UInt32, name, qos) for name in subs}
            hot = [subs[name] for name in ('c', 'a', 'd', 'b')]
            executor = HotPathExecutor(lambda: (hot, []), slow_period_s=3600.0, context=ctx)
            executor.add_node(node)
            executor.spin_once(timeout_sec=0.0)   # its first slow pass, with nothing queued yet
            deadline = time.monotonic() + TIMEOUT_S
            while any(pub.get_subscription_count() < 1 for pub in pubs.values()):
                assert time.monotonic() < deadline, 'a subscription never matched its own node\'s publisher'
                executor.spin_once(timeout_sec=0.01)
            for name in ('a', 'b', 'd'):   # c is not ready: not served
                pubs[name].publish(UInt32(data=1))
            executor.spin_once(timeout_sec=TIMEOUT_S)
            assert got == ['a', 'd', 'b']
            executor.shutdown()
            node.destroy_node()
        finally:
            rclpy.shutdown(context=ctx)
