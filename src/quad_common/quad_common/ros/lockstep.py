"""Lockstep followers: nodes whose record of the run must be complete (the recorder, fly's flight monitor).

The lockstep simulator publishes step k only once every follower has acknowledged taking an odom stamped at or
after t_k - FOLLOWER_LAG_STEPS periods. A follower acknowledges on `<name>/lockstep_ack` (rosgraph_msgs/Clock:
the newest odom stamp it has taken) every ACK_EVERY steps it has taken (newer stamps, however many vehicles'
odometry and /clock messages a step holds: a fleet's recorder acknowledges as often as one vehicle's). So at most
FOLLOWER_LAG_STEPS + 1 steps are unacknowledged, and every publisher paced by the lockstep keeps HISTORY_DEPTH > that
in its (reliable) history: a slow follower slows the simulation down instead of losing samples.
"""

import time

from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock

FOLLOWER_LAG_STEPS = 40
ACK_EVERY = 10
HISTORY_DEPTH = 2 * FOLLOWER_LAG_STEPS + 20   # > FOLLOWER_LAG_STEPS + ACK_EVERY + the step in flight
PACED = QoSProfile(depth=HISTORY_DEPTH, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE)
ACK_FLUSH_S = 0.05   # wall time: a follower acknowledges its newest odometry at least this often (a stopping simulator
# waits for the last step's); more often only costs: each acknowledgement is a publish here and a wake-up there
ACK = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
assert ACK_EVERY < FOLLOWER_LAG_STEPS  # else the simulator could wait for an ack the follower never sends


def ack_topic(follower: str) -> str:
    return f'/{follower.strip("/")}/lockstep_ack'


class Acknowledger:
    """A follower's side: `taken(stamp_ns)` for every odom taken; publishes every ACK_EVERY-th newer stamp (and
    `flush()`); a stamp not newer than the newest taken (another vehicle's odometry of the same step) counts
    nothing."""

    def __init__(self, node, follower: str):
        self._pub = node.create_publisher(Clock, ack_topic(follower), ACK)
        self._pending = 0
        self._held = False
        self.newest_ns = -1
        self._next_flush_s = 0.0

    def hold(self, held: bool):
        """While held, nothing is acknowledged (the simulator waits at the first step): a follower that needs
        something first, e.g. the plan, holds until it has it."""
        self._held = held

    def taken(self, stamp_ns: int):
        if stamp_ns <= self.newest_ns:
            return
        self.newest_ns = stamp_ns
        self._pending += 1
        if self._pending >= ACK_EVERY:
            self.flush()

    def flush_if_due(self):
        """flush() if ACK_FLUSH_S of wall time passed since the last one: a follower that flushes after each spin
        would acknowledge every step, not every ACK_EVERY-th."""
        if time.monotonic() >= self._next_flush_s:
            self.flush()

    def flush(self):
        self._next_flush_s = time.monotonic() + ACK_FLUSH_S
        if self._pending and not self._held:
            self._pending = 0
            msg = Clock()
            msg.clock.sec, msg.clock.nanosec = divmod(self.newest_ns, 1_000_000_000)
            self._pub.publish(msg)
