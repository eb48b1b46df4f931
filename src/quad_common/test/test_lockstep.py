"""A lockstep follower's acknowledgements (quad_common.ros.lockstep.Acknowledger), without a graph."""

import time

from quad_common.ros import lockstep


class _Node:
    """Stands in for an rclpy node: records what the acknowledger publishes."""

    def __init__(self):
        self.sent = []

    def create_publisher(self, msg_type, topic, qos):
        node = self

        class Publisher:
            def publish(self, msg):
                node.sent.append(msg.clock.sec * 1_000_000_000 + msg.clock.nanosec)
        return Publisher()


def test_a_follower_that_flushes_each_spin_acknowledges_every_ack_every_th_step_and_after_a_pause():
    node = _Node()
    ack = lockstep.Acknowledger(node, 'fly_monitor')
    ack.taken(10_000_000)
    ack.flush_if_due()   # the first one goes at once (the simulator waits at step 0 for it)
    assert node.sent == [10_000_000]
    for k in range(2, lockstep.ACK_EVERY + 1):   # one odometry per spin, each spin ending with flush_if_due
        ack.taken(k * 10_000_000)
        ack.flush_if_due()
    assert node.sent == [10_000_000]   # within ACK_FLUSH_S: held until ACK_EVERY of them
    ack.taken((lockstep.ACK_EVERY + 1) * 10_000_000)
    assert node.sent == [10_000_000, (lockstep.ACK_EVERY + 1) * 10_000_000]
    ack.taken((lockstep.ACK_EVERY + 2) * 10_000_000)
    deadline = time.monotonic() + 5.0
    while len(node.sent) < 3 and time.monotonic() < deadline:   # a stopping simulator: the rest after ACK_FLUSH_S
        ack.flush_if_due()
    assert node.sent[-1] == (lockstep.ACK_EVERY + 2) * 10_000_000


def test_a_fleet_follower_counts_steps_not_messages():
    """Sixteen vehicles' odometry of one step is one step taken: the acknowledgement goes every ACK_EVERY steps,
    as one vehicle's would, not every ACK_EVERY messages."""
    node = _Node()
    ack = lockstep.Acknowledger(node, 'recorder')
    ack.taken(0)
    ack.flush()
    for step in range(1, lockstep.ACK_EVERY):
        for _vehicle in range(16):
            ack.taken(step * 10_000_000)
    assert node.sent == [0]
    for _vehicle in range(16):
        ack.taken(lockstep.ACK_EVERY * 10_000_000)
    assert node.sent == [0, lockstep.ACK_EVERY * 10_000_000]
    ack.taken(5 * 10_000_000)   # an older stamp (reordered) neither counts nor moves the newest back
    ack.flush()
    assert node.sent == [0, lockstep.ACK_EVERY * 10_000_000]
