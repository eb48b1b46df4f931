"""SerializedPublisher: a message or its CDR bytes arrive as rclpy's publish would send them; a write rcl refuses
raises, naming the topic and rcl's reason. (That its write leaves the interpreter lock free is tested where it
matters, in the bridge's graph: test/bridge/test_bridge_dds_block.py.)"""

import time

import pytest
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from std_msgs.msg import String

from quad_common.ros.rcl_serialized import SerializedPublisher
from quad_common.ros.testing import TIMEOUT_S, isolated_domain


@pytest.fixture
def node():
    with isolated_domain() as (domain, _):
        ctx = rclpy.Context()
        rclpy.init(context=ctx, domain_id=domain)
        try:
            yield rclpy.create_node('serialized_publisher', context=ctx)
        finally:
            ctx.try_shutdown()


def test_messages_and_their_bytes_arrive_as_published(node):
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    got = []
    node.create_subscription(String, 'said', lambda msg: got.append(msg.data), qos)
    publisher = SerializedPublisher(node.create_publisher(String, 'said', qos))
    executor = rclpy.executors.SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    deadline = time.monotonic() + TIMEOUT_S
    while publisher.publisher.get_subscription_count() < 1:
        assert time.monotonic() < deadline, 'the subscription never matched its own node\'s publisher'
        executor.spin_once(timeout_sec=0.01)
    publisher.publish(String(data='a message'))
    publisher.publish(serialize_message(String(data='its bytes')))
    while len(got) < 2 and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    assert got == ['a message', 'its bytes']
    executor.shutdown()


def test_a_write_rcl_refuses_raises_naming_the_topic_and_why(node):
    publisher = SerializedPublisher(node.create_publisher(String, 'said', 10))
    node.context.try_shutdown()   # the publisher's context is no longer valid: rcl refuses the write
    with pytest.raises(RuntimeError, match=r'publish on /said failed \(\d+\): .*publisher'):
        publisher.publish(String(data='too late'))
