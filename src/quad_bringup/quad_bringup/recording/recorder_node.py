"""Node `recorder`: raw (serialized) subscriptions -> a rosbag2 bag (MCAP), see recorder.py.

Topics of DEFAULT_TOPICS, and a fleet vehicle's namespaced ones (/cf1/odom: recorder.contract_spec), are
subscribed at once with the QoS their publishers use (latched trajectory topics transient_local); any other topic
is subscribed when it appears in the graph, with its type and durability taken from its publishers. Timestamps
are receive times (system clock, as `ros2 bag record` does). SIGINT/SIGTERM/SIGHUP close the bag cleanly, and so
does the death of the process that started it (quad_common.lifeline.bind_to_parent).

A lockstep follower (quad_common.ros.lockstep): it acknowledges the odometry it has written, so a simulator started
with lockstep_followers:=recorder never publishes more than the bag can take. The subscriptions are served in
one pass per wake-up (HotPathExecutor), each ready one's whole backlog in it, and after a wake-up that took messages
it pauses take_pause_s (a lockstep step's messages come one by one over its controllers' ticks: taken as they came,
each would cost a wake-up and a pass over every subscription); the status timer, the bag's flush and discovery in
its slow pass (the flush's fsync in a thread of its own: recorder.BagRecorder.flush).

Status on `diagnostics` (name `recorder`, one value per topic: messages written) every second and when a topic
gets its first message: how `quadflight fly` knows the latched plan is in the bag before the flight starts.
"""

import importlib
import signal
import struct
import sys
import time

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry
from rclpy.executors import ExternalShutdownException
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

from quad_bringup.recording.recorder import DEFAULT_TOPICS, BagRecorder, TopicSpec, contract_spec, installed
from quad_common import contract, diagnostics, node_start
from quad_common.lifeline import bind_to_parent
from quad_common.params import Param
from quad_common.realtime import freeze_startup_heap
from quad_common.ros import cdr, lockstep
from quad_common.ros.hot_path import HotPathExecutor
from quad_common.ros.node_main import STOP_SIGNALS, close_nodes, ignore_stop_signals, lean_log_caller, rcl_reason
from quad_common.ros.ros_params import ParameterSet

STATUS_PERIOD_S = 1.0
DRAIN_PASS_S = 0.2  # wall time: the drain after a stop ends when this long took nothing sent before it
# messages taken from a ready subscription per wake-up (quad_common.ros.hot_path): a fleet's recorder woke ~9 times a
# lockstep step, each wake-up a pass over its every subscription (~0.3 ms at 65 of them) for a message or two
TAKES_PER_PASS = 100
ODOM = 'odom'
CLOCK = contract.CLOCK


def _clock_ns(data: bytes) -> int:
    """The time of a serialized rosgraph_msgs/Clock (CDR: 4-byte encapsulation, then sec int32, nanosec uint32)."""
    sec, nanosec = struct.unpack_from('<iI' if data[1] == 1 else '>iI', data, 4)
    return sec * 1_000_000_000 + nanosec

SPECS = [
    Param('output_dir', '', 'bag directory to create (must not exist yet)', read_only=True),
    Param('topics', list(DEFAULT_TOPICS), 'topics to record (relative names resolve in the node namespace)',
          read_only=True),
    Param('flush_period_s', 1.0, 'wall-clock period of pushing the open chunk to disk (what a SIGKILL can lose)',
          min=0.05, max=60.0),
    Param('lockstep_ack_after', '', 'comma-separated topics that must be in the bag before odometry is '
          'acknowledged (quad_common.ros.lockstep: a follower\'s simulator does not start without them), '
          'e.g. trajectory',
          read_only=True),
    Param('take_pause_s', 0.005, 'wall time the recorder pauses after a wake-up that took messages: a burst (a '
          "lockstep step's odometry and setpoints, published one by one over its controllers' ticks) is then taken in "
          'one wake-up, each a pass over every subscription, not one per message; a message reaches the bag at most '
          'this much later (the lockstep holds only a follower 40 steps behind)',
          min=0.0, max=0.1, read_only=True),
    Param('queue_depth', 1000, 'subscription history depth (reliable; generous so a busy recorder drops nothing)',
          min=1, max=100000, read_only=True),
]


def message_class(msgtype: str):
    """nav_msgs/msg/Odometry -> the rclpy message class."""
    package, _, name = msgtype.split('/')
    return getattr(importlib.import_module(f'{package}.msg'), name)


class RecorderNode(Node):
    def __init__(self, **kwargs):
        super().__init__('recorder', **kwargs)
        self.params = ParameterSet(self, SPECS)
        if not self.params['output_dir']:
            raise ValueError('output_dir = \'\' refused: give the bag directory to create')
        self.bag = BagRecorder(self.params['output_dir'])
        self.closed = False
        self.ack = lockstep.Acknowledger(self, self.get_name())
        self.ack_after = [t.strip() for t in self.params['lockstep_ack_after'].split(',') if t.strip()]
        self.awaiting = list(self.ack_after)   # those of ack_after not in the bag yet
        self._raw_subscriptions = {}
        self.steps_until_take = {}   # topic -> lockstep steps until its next take (take_step)
        # the stop's wall time (ns; none yet: the largest int64) and how many messages published before it (their
        # publisher's source timestamp) were taken: what the drain after a stop waits for
        self.stop_ns = 2 ** 63 - 1
        self.sent_before_stop = 0
        self._pending = []
        # the lockstep steps it acknowledges: the newest odom and /clock stamps all taken (a step's /clock follows
        # its odom on the wire; acknowledging odom alone let the simulator exit with its last /clock unsent); a
        # fleet's: every vehicle's odom (/cf1/odom, ...) and /clock
        self._paced_newest_ns = {t: -1 for t in self.params['topics']
                                 if t == CLOCK or contract.contract_name(t) == ODOM}
        for topic in self.params['topics']:
            spec = contract_spec(topic)
            if spec is None:
                self._pending.append(topic)
            elif not installed(spec):  # e.g. tf2_msgs is not among the PyPI ROS wheels
                self.get_logger().warning(f'not recording {topic}: {spec.msgtype} is not installed')
            else:
                self._subscribe(topic, spec)
        steady = rclpy.clock.Clock(clock_type=rclpy.clock.ClockType.STEADY_TIME)
        self.create_timer(self.params['flush_period_s'], self.bag.flush, clock=steady)
        self.status_pub = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS,
                                                contract.qos(contract.DIAGNOSTICS))
        self.create_timer(STATUS_PERIOD_S, self.publish_status, clock=steady)
        self.ack_timer = self.create_timer(lockstep.ACK_FLUSH_S, self.ack.flush, clock=steady)
        if self._pending:
            self.create_timer(0.5, self._discover,
                              clock=rclpy.clock.Clock(clock_type=rclpy.clock.ClockType.STEADY_TIME))
        self.get_logger().info(f'recording {len(self.params["topics"])} topics to {self.params["output_dir"]}')

    def _subscribe(self, topic: str, spec: TopicSpec):
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST,
                         depth=1 if spec.latched else self.params['queue_depth'],
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL if spec.latched else DurabilityPolicy.VOLATILE)
        self.bag.add_topic(topic, spec, depth=qos.depth)

        def on_message(data: bytes, info: dict, topic=topic):
            if self.closed:   # hosted: closed at the simulator's stop, while the other nodes still publish
                return
            self.bag.write(topic, time.time_ns(), data)
            if info['source_timestamp'] <= self.stop_ns:
                self.sent_before_stop += 1
            if topic in self._paced_newest_ns:
                stamp_ns = _clock_ns(data) if topic == CLOCK else cdr.header_stamp_ns(data, Odometry)
                if stamp_ns > self._paced_newest_ns[topic]:
                    self._paced_newest_ns[topic] = stamp_ns
                self.ack.taken(min(self._paced_newest_ns.values()))
                if self.awaiting:  # nothing acknowledged until the bag has these (e.g. the latched plan)
                    self.awaiting = [t for t in self.awaiting if self.bag.counts.get(t, 0) == 0]
                    self.ack.hold(bool(self.awaiting))
            if self.bag.counts[topic] == 1:
                self.publish_status()

        self._raw_subscriptions[topic] = self.create_subscription(message_class(spec.msgtype), topic, on_message, qos,
                                                              raw=True)

    def publishers_left(self) -> bool:
        """Whether a recorded topic has a publisher other than this node's status publisher."""
        own = self.status_pub.topic_name
        return any(sub.get_publisher_count() > (sub.topic_name == own) for sub in self._raw_subscriptions.values())

    def hot_entities(self):
        return list(self._raw_subscriptions.values()), [self.ack_timer]

    def _discover(self):
        """Subscribe to requested topics that have appeared in the graph since."""
        types = dict(self.get_topic_names_and_types())
        for topic in list(self._pending):
            full = self.resolve_topic_name(topic)
            if full not in types:
                continue
            publishers = self.get_publishers_info_by_topic(full)
            latched = bool(publishers) and all(p.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
                                               for p in publishers)
            try:
                self._subscribe(topic, TopicSpec(types[full][0], latched))
            except (ValueError, ImportError) as exc:
                self.get_logger().error(str(exc))
            self._pending.remove(topic)

    def publish_status(self):
        counts = {topic: self.bag.counts.get(topic, 0) for topic in self.params['topics']}
        self.status_pub.publish(diagnostics.array(self.get_clock().now().to_msg(), [diagnostics.status(
            contract.RECORDER_STATUS, diagnostics.OK, f'{self.bag.total} messages', counts)]))

    def close_bag(self):
        """Finish the bag (once: a second call does nothing)."""
        if self.closed:
            return
        self.closed = True
        self.bag.close()
        self.get_logger().info(f'bag closed: {self.bag.total} messages '
                               + ', '.join(f'{t}={n}' for t, n in self.bag.counts.items() if n))

    def destroy_node(self):
        """Closes the bag first, whatever ended the process that hosts this node (quad_bringup.running.node_host: a
        stop, or another hosted node's exception)."""
        try:
            self.close_bag()
        finally:
            super().destroy_node()


def record(node: RecorderNode, executor, stop: list, sleep=time.sleep):
    """Spins until `stop` holds a signal, pausing take_pause_s after every wake-up that took a message (a
    SIGTERM in the pause is seen at its end)."""
    pause_s = node.params['take_pause_s']
    while not stop:
        written = node.bag.total
        executor.spin_once(timeout_sec=0.1)
        if pause_s and node.bag.total != written:
            sleep(pause_s)


def drain(node: RecorderNode, executor, pass_s: float = DRAIN_PASS_S):
    """Takes what was published before the stop: spins until pass_s has passed without a message whose publisher
    sent it before now, or, sooner, until no recorded topic has a publisher left (once a writer is gone its
    reader keeps what it had received and drops what comes after: waiting longer cannot bring more), then takes
    what is there. What a publisher sends after the stop is still written while the drain lasts, but does not
    prolong it: publishers that never stop do not keep the recorder alive."""
    node.stop_ns = time.time_ns()
    taken = node.sent_before_stop
    deadline = time.monotonic() + pass_s
    while time.monotonic() < deadline:
        if not node.publishers_left():
            take_queued(node)
            return
        executor.spin_once(timeout_sec=0.01)
        if node.sent_before_stop != taken:
            taken = node.sent_before_stop
            deadline = time.monotonic() + pass_s


# lockstep steps between takes of a subscription whose last take found nothing (take_step)
IDLE_TAKE_EVERY_STEPS = 8


def _take_all(sub) -> int:
    """Writes every message `sub` holds now (its callback), taken without a wait set; how many."""
    taken = 0
    with sub.handle:
        while (message := sub.handle.take_message(sub.msg_type, True)) is not None:
            sub.callback(*message)
            taken += 1
    return taken


def take_ready(node: RecorderNode) -> int:
    """Writes every message its subscriptions hold now, taken without a wait set; returns how many."""
    return sum(_take_all(sub) for sub in node._raw_subscriptions.values())


def take_step(node: RecorderNode):
    """A hosted recorder's turn in each lockstep step (SimNode.each_step, quad_bringup.running.node_host): what is
    queued, then its acknowledgements when due. Its subscriptions are out of the host's wait set (at 16 vehicles ~65
    of them cost ~150 us in every pass of the lockstep's loop); a take from an empty queue costs ~1.5 us. A
    subscription whose last take found nothing (a fleet's plans and diagnostics: half of them) is taken again
    IDLE_TAKE_EVERY_STEPS steps later; one that found a message at the next step (odometry, setpoints, /clock: every
    step); all of them while it waits for a topic before acknowledging (lockstep_ack_after: the plan, which the
    simulator's first step waits for)."""
    if node.closed:
        return
    if node.awaiting:
        take_ready(node)
    else:
        wait = node.steps_until_take
        for topic, sub in node._raw_subscriptions.items():
            if wait.get(topic, 0):
                wait[topic] -= 1
            else:
                wait[topic] = 0 if _take_all(sub) else IDLE_TAKE_EVERY_STEPS - 1
    node.ack.flush_if_due()


def take_queued(node: RecorderNode):
    """Writes what the subscriptions hold now, and what writing it let in, without waiting for more. After a stop in a
    process that hosts the recorder beside the simulator (quad_bringup.running.node_host) this is the whole drain: a
    publisher in the same process delivers as it publishes, so what the simulator's own drain made it publish is
    already queued here."""
    while take_ready(node):
        pass


def main(args=None):
    """Spins until SIGINT/SIGTERM/SIGHUP (or the parent's death), then drains what was published before the stop and
    closes the bag."""
    stop = node_start.received   # a stop recorded since the console script's first line counts
    for sig in STOP_SIGNALS:
        signal.signal(sig, lambda signum, frame: stop.append(signum))
    bind_to_parent()
    lean_log_caller()
    if stop:   # Ctrl-C before anything was built
        ignore_stop_signals()
        return
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except _rclpy.RCLError as exc:   # a missing or malformed --params-file
        print(f'[ERROR] [recorder]: recorder refused to start: {rcl_reason(exc)}', file=sys.stderr)
        sys.exit(2)
    try:
        node = RecorderNode()
    except Exception as exc:  # bad parameters, an existing bag directory, an unknown type
        print(f'recorder: {exc}', file=sys.stderr)
        rclpy.try_shutdown()
        sys.exit(2)
    executor = HotPathExecutor(node.hot_entities, takes_per_pass=TAKES_PER_PASS)
    executor.add_node(node)
    freeze_startup_heap()   # no full collection of the start-up heap while recording (as quad_common.ros.node_main)
    try:
        record(node, executor, stop)
        drain(node, executor)
    except ExternalShutdownException:
        pass
    finally:
        node.close_bag()
        close_nodes(executor, [node])
        rclpy.try_shutdown()
        ignore_stop_signals()


if __name__ == '__main__':
    main()
