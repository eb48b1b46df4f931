"""The recorder node in a real graph: a test publisher, the bag read back with rosbags."""

import shutil
import signal
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from types import SimpleNamespace

import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosbags.rosbag2 import Reader
from rosgraph_msgs.msg import Clock
from std_msgs.msg import String
from trajectory_msgs.msg import MultiDOFJointTrajectory

from quad_bringup.commands.record import ros_arguments
from quad_bringup.recording.recorder import open_bag_reader, repair_bag, typestore
from quad_common import contract
from quad_common.ros.testing import isolated_domain

N_ODOM = 300
N_CLOCK = 40
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
TIMEOUT_S = 120.0


@pytest.fixture
def graph():
    with isolated_domain() as (domain, env):
        ctx = rclpy.Context()
        rclpy.init(context=ctx, domain_id=domain)
        node = rclpy.create_node('recorder_test_talker', context=ctx)
        yield node, env
        node.destroy_node()
        rclpy.shutdown(context=ctx)


def start_recorder(bag, env, topics):
    cmd = [sys.executable, '-m', 'quad_bringup.recording.recorder_node',
           *ros_arguments(bag, topics, flush_period_s=0.1)]
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def wait_for(condition, what):
    """Polls a condition (an event we cannot block on) with a generous deadline."""
    deadline = time.monotonic() + TIMEOUT_S
    while not condition():
        assert time.monotonic() < deadline, f'timed out waiting for {what}'
        time.sleep(0.05)


def flushed_counts(bag, tmp_path):
    """Message counts of what the running recorder has flushed so far (read from a repaired copy)."""
    copy = tmp_path / 'copy'
    shutil.rmtree(copy, ignore_errors=True)
    try:
        shutil.copytree(bag, copy)
        repair_bag(copy)
        with Reader(copy) as reader:
            return {c.topic: c.msgcount for c in reader.connections}
    except Exception:
        return {}


def publish_flight(node, env, bag, tmp_path):
    """Latched trajectory before the recorder starts; odom, clock and a discovered topic after."""
    traj_pub = node.create_publisher(MultiDOFJointTrajectory, 'trajectory', LATCHED)
    traj = MultiDOFJointTrajectory()
    traj.header.frame_id = 'map'
    traj.joint_names = ['base_link']
    traj_pub.publish(traj)
    odom_pub = node.create_publisher(Odometry, 'odom', 10)
    clock_pub = node.create_publisher(Clock, '/clock', 10)
    chatter_pub = node.create_publisher(String, 'chatter', 10)
    proc = start_recorder(bag, env, ['trajectory', 'odom', '/clock', 'chatter'])
    pubs = [odom_pub, clock_pub, chatter_pub, traj_pub]
    wait_for(lambda: all(p.get_subscription_count() > 0 for p in pubs) or proc.poll() is not None,
             'the recorder to subscribe')
    assert proc.poll() is None, proc.stdout.read()
    for k in range(N_ODOM):
        msg = Odometry()
        msg.header.stamp.sec, msg.header.stamp.nanosec = k // 100, (k % 100) * 10_000_000
        msg.pose.pose.position.x = 0.001 * k
        odom_pub.publish(msg)
        if k % (N_ODOM // N_CLOCK) == 0 and k // (N_ODOM // N_CLOCK) < N_CLOCK:
            clock_pub.publish(Clock(clock=msg.header.stamp))
    chatter_pub.publish(String(data='hello bag'))
    for p in pubs:
        assert p.wait_for_all_acked()
    expected = {'trajectory': 1, 'odom': N_ODOM, '/clock': N_CLOCK, 'chatter': 1}
    wait_for(lambda: flushed_counts(bag, tmp_path) == expected, f'the recorder to flush {expected}')
    return proc, expected


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM], ids=['SIGINT', 'SIGTERM'])
def test_recorder_writes_every_message_and_closes_on_signal(graph, tmp_path, sig):
    node, env = graph
    bag = tmp_path / 'bag'
    proc, expected = publish_flight(node, env, bag, tmp_path)
    proc.send_signal(sig)
    out, _ = proc.communicate(timeout=TIMEOUT_S)
    assert proc.returncode == 0, out
    assert f'bag closed: {sum(expected.values())} messages' in out  # delivered == written
    ts = typestore()
    with Reader(bag) as reader:  # closed cleanly: metadata.yaml and a full MCAP summary
        conns = {c.topic: c for c in reader.connections}
        assert {t: c.msgcount for t, c in conns.items()} == expected
        assert conns['odom'].digest == ts.hash_rihs01('nav_msgs/msg/Odometry')
        assert conns['chatter'].msgtype == 'std_msgs/msg/String'
        assert conns['trajectory'].ext.offered_qos_profiles[0].durability.name == 'TRANSIENT_LOCAL'
        xs = [ts.deserialize_cdr(raw, c.msgtype).pose.pose.position.x
              for c, _, raw in reader.messages(connections=[conns['odom']])]
        texts = [ts.deserialize_cdr(raw, c.msgtype).data
                 for c, _, raw in reader.messages(connections=[conns['chatter']])]
        stamps = [t for _, t, _ in reader.messages()]
    assert xs == pytest.approx([0.001 * k for k in range(N_ODOM)])
    assert texts == ['hello bag']
    assert all(abs(t - time.time_ns()) < 3600e9 for t in stamps)  # receive times on the system clock


def test_recorder_stopped_beside_a_publisher_that_never_stops_exits_with_all_sent_before_the_stop(graph, tmp_path):
    """The drain after a stop ends at messages sent after it: a publisher still publishing does not keep the
    recorder alive, and every message sent before the stop is in the bag (a contiguous prefix of the stream)."""
    node, env = graph
    bag = tmp_path / 'bag'
    keep_all = QoSProfile(depth=100000, reliability=ReliabilityPolicy.RELIABLE)
    pub = node.create_publisher(String, 'chatter', keep_all)
    proc = start_recorder(bag, env, ['chatter'])
    wait_for(lambda: pub.get_subscription_count() > 0 or proc.poll() is not None, 'the recorder to subscribe')
    assert proc.poll() is None, proc.stdout.read()
    sent, stop = [0], threading.Event()

    def publish_forever():   # about 1 kHz, until the test ends (long after the recorder's stop)
        while not stop.is_set():
            pub.publish(String(data=str(sent[0])))
            sent[0] += 1
            time.sleep(0.001)   # the stream's period, not synchronisation

    publisher = threading.Thread(target=publish_forever, daemon=True)
    publisher.start()
    try:
        wait_for(lambda: sent[0] >= 500, 'the stream to run')
        sent_before_stop = sent[0]
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=60.0)   # a hang guard: the drain takes tenths of a second
    finally:
        stop.set()
        publisher.join()
    assert proc.returncode == 0, out
    ts = typestore('std_msgs/msg/String')   # not a contract type: the whole store, whatever was built before
    with Reader(bag) as reader:
        numbers = [int(ts.deserialize_cdr(raw, c.msgtype).data) for c, _, raw in reader.messages()]
    assert numbers == list(range(len(numbers))) and len(numbers) >= sent_before_stop, (len(numbers), sent_before_stop)


def test_killed_recorder_leaves_a_readable_bag(graph, tmp_path):
    node, env = graph
    bag = tmp_path / 'bag'
    proc, expected = publish_flight(node, env, bag, tmp_path)
    proc.kill()
    proc.communicate(timeout=TIMEOUT_S)
    assert not (bag / 'metadata.yaml').exists()
    before = {f.name: f.read_bytes() for f in bag.iterdir()}
    reader, repair = open_bag_reader(bag)  # reads a repaired copy: torn record cut, footer, metadata.yaml
    try:
        assert {f.name: f.read_bytes() for f in bag.iterdir()} == before   # the input is never modified
        assert repair is not None and Path(repair.repaired_copy) == bag.with_name('bag.repaired')
        assert 0 < repair.cut_at_byte <= repair.size_bytes == len(before[Path(repair.file).name])
        assert {c.topic: c.msgcount for c in reader.connections} == expected
        ts = typestore()
        odom = [c for c in reader.connections if c.topic == 'odom']
        xs = [ts.deserialize_cdr(raw, c.msgtype).pose.pose.position.x for c, _, raw in reader.messages(odom)]
    finally:
        reader.close()
    assert xs == pytest.approx([0.001 * k for k in range(N_ODOM)])
    # `quadflight report` on it: exit 0, the input untouched, and report.md says where it was cut and the copy
    done = subprocess.run([sys.executable, '-m', 'quad_bringup.cli', 'report', str(bag), '--out',
                           str(tmp_path / 'report')], env=env, capture_output=True, text=True, timeout=TIMEOUT_S)
    assert {f.name: f.read_bytes() for f in bag.iterdir()} == before
    text = done.stdout  # printed first: it holds even when the bag then lacks what a flight report needs
    assert f'was cut at byte {repair.cut_at_byte} of {repair.size_bytes}' in text
    assert str(bag.with_name('bag.repaired')) in text


def test_recorder_refuses_an_existing_bag_directory(graph, tmp_path):
    _, env = graph
    (tmp_path / 'bag').mkdir()
    proc = start_recorder(tmp_path / 'bag', env, ['odom'])
    out, _ = proc.communicate(timeout=TIMEOUT_S)
    assert proc.returncode == 2
    assert 'exists already' in out


def test_recorder_status_goes_under_the_contracts_name_whatever_the_node_is_called(graph, tmp_path):
    """fly's monitor reads the bag's counts from the status named contract.RECORDER_STATUS, not the node's name."""
    node, env = graph
    statuses = []
    node.create_subscription(DiagnosticArray, contract.DIAGNOSTICS, lambda msg: statuses.extend(msg.status), 10)
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    args = ['__node:=bag_writer' if a == '__node:=recorder' else a for a in ros_arguments(tmp_path / 'bag', ['odom'])]
    proc = subprocess.Popen([sys.executable, '-m', 'quad_bringup.recording.recorder_node', *args], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + TIMEOUT_S
        while not statuses:   # the recorder's status every STATUS_PERIOD_S: a message to wait on
            assert time.monotonic() < deadline and proc.poll() is None, 'no status from the recorder'
            executor.spin_once(timeout_sec=0.1)
    finally:
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=TIMEOUT_S)
        executor.shutdown()
    assert [(s.name, {kv.key: kv.value for kv in s.values}) for s in statuses[:1]] == \
        [(contract.RECORDER_STATUS, {'odom': '0'})], out


def test_a_fleet_vehicles_topics_have_the_contracts_specs():
    from quad_bringup.recording.recorder import DEFAULT_TOPICS, contract_spec
    assert contract_spec('/cf1/odom') == DEFAULT_TOPICS['odom']
    assert contract_spec('/cf1/cmd/attitude_thrust') == DEFAULT_TOPICS['cmd/attitude_thrust']
    assert contract_spec('/cf1/trajectory') == DEFAULT_TOPICS['trajectory'] and DEFAULT_TOPICS['trajectory'].latched
    assert contract_spec('/cf1/trajectory/path') == DEFAULT_TOPICS['trajectory/path']
    assert contract_spec('/clock') == DEFAULT_TOPICS['/clock'] and contract_spec('/cf1/unknown') is None


@contextmanager
def recorder_in_process(bag, topics: str):
    """A RecorderNode in this process (as node_host hosts it), writing `bag`, recording `topics` (a parameter
    value, e.g. '["odom"]'), in a context of its own on an isolated domain: yields (node, context)."""
    from quad_bringup.recording.recorder_node import RecorderNode

    with isolated_domain() as (domain, _):
        ctx = rclpy.Context()
        rclpy.init(context=ctx, domain_id=domain, args=['--ros-args', '-p', f'output_dir:={bag}', '-p',
                                                        f'topics:={topics}'])
        try:
            yield RecorderNode(context=ctx), ctx
        finally:
            rclpy.shutdown(context=ctx)


def test_a_hosted_recorder_closes_its_bag_when_destroyed(tmp_path):
    """In a process that hosts it beside other nodes (quad_bringup.running.node_host), whatever ends the process
    destroys the nodes (quad_common.ros.node_main.close_nodes): the recorder closes its bag then, once."""
    bag = tmp_path / 'bag'
    with recorder_in_process(bag, '["odom"]') as (node, _):
        node.bag.write('odom', 1, b'\x00\x01\x00\x00' + bytes(300))   # a little-endian CDR body
        node.destroy_node()
        assert (bag / 'metadata.yaml').exists()
        node.close_bag()   # a second close (the standalone recorder's own, then its teardown's) does nothing
    with Reader(bag) as reader:   # closed: metadata.yaml and the MCAP footer written
        assert {c.topic: c.msgcount for c in reader.connections} == {'odom': 1}


def test_a_recorder_beside_a_lockstep_simulator_takes_each_step_without_the_wait_set(tmp_path):
    """node_host serves a recorder beside a lockstep simulator once a step (take_step), its subscriptions out of the
    host's wait set: everything published in the process since the last step is written then (a publisher in the
    process delivers as it publishes), acknowledged when due, and nothing is taken twice; a topic whose last take
    found nothing is taken again IDLE_TAKE_EVERY_STEPS steps later, nothing lost. Beside a realtime simulator it
    stays in the wait set."""
    from quad_bringup.recording.recorder_node import IDLE_TAKE_EVERY_STEPS, take_step
    from quad_bringup.running.node_host import RECORDER, SIMULATOR, hot_entities, taken_per_step

    topics = '["/clock", "/cf1/odom", "/cf1/diagnostics"]'
    with recorder_in_process(tmp_path / 'bag', topics) as (node, ctx):
        simulator = SimpleNamespace(params={'mode': 'lockstep'})
        entries = [(SIMULATOR, ''), (RECORDER, '')]
        assert taken_per_step(entries, [simulator, node]) == [node]
        assert taken_per_step(entries, [SimpleNamespace(params={'mode': 'realtime'}), node]) == []
        assert taken_per_step([(SIMULATOR, '')], [simulator]) == []
        assert hot_entities([node])[0], 'a standalone recorder is served by its wait set'
        talker = rclpy.create_node('talker', context=ctx)
        odom = talker.create_publisher(Odometry, '/cf1/odom', 10)
        clock = talker.create_publisher(Clock, '/clock', 10)
        diagnostics = talker.create_publisher(DiagnosticArray, '/cf1/diagnostics', 10)
        written = 0
        for step in range(1, IDLE_TAKE_EVERY_STEPS + 2):
            for _ in range(step % 3 + 1):
                msg = Odometry()
                msg.header.stamp.sec = step
                odom.publish(msg)
                clock.publish(Clock(clock=msg.header.stamp))
                written += 1
            take_step(node)
            if step == 1:   # after a take that found none: taken IDLE_TAKE_EVERY_STEPS steps later
                diagnostics.publish(DiagnosticArray())
            assert node.bag.counts['/clock'] == node.bag.counts['/cf1/odom'] == written, (step, node.bag.counts)
            assert node.bag.counts['/cf1/diagnostics'] == (step > IDLE_TAKE_EVERY_STEPS), (step, node.bag.counts)
        node.ack._next_flush_s = 0.0   # due: the newest step acknowledged
        take_step(node)
        assert node.ack.newest_ns == (IDLE_TAKE_EVERY_STEPS + 1) * 1_000_000_000 and node.ack._pending == 0
        node.destroy_node()
        talker.destroy_node()
