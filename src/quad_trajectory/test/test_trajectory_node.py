"""trajectory_node in a real rclpy graph (DDS, own domain), driven by a probe node.

Everything waits on messages or conditions, never on elapsed time.
"""

import os
import subprocess
import sys
import time

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from trajectory_msgs.msg import MultiDOFJointTrajectory
from visualization_msgs.msg import Marker, MarkerArray

from quad_common import diagnostics
from quad_common.conversions import msg_to_sampled, stamp_to_s
from quad_common.ros.testing import ProbeGraph, isolated_domain, probe_graph
from quad_trajectory import trajectory_node
from quad_trajectory.mission import DEFAULT_MISSION_PATH, load_mission, plan_mission
from quad_trajectory.trajectory_node import TrajectoryNode

RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
FLAT = [0.0, 0.0, 1.0, 1.0, 0.0, 1.0, 1.0, 1.0, 1.5]
_FLEETS = os.path.join(os.path.dirname(os.path.dirname(DEFAULT_MISSION_PATH)), 'missions', 'fleets')
FORMATION, CROSSING = os.path.join(_FLEETS, 'formation4.yaml'), os.path.join(_FLEETS, 'crossing2.yaml')


class Graph(ProbeGraph):
    def __init__(self, ctx):
        super().__init__(ctx)
        self.waypoints_pub = self.probe.create_publisher(Path, 'waypoints', RELIABLE)
        self.got = {'trajectory': [], 'trajectory/path': [], 'trajectory/waypoints': [], 'trajectory/markers': [],
                    'diagnostics': []}
        for topic, kind in (('trajectory', MultiDOFJointTrajectory), ('trajectory/path', Path),
                            ('trajectory/waypoints', Path), ('trajectory/markers', MarkerArray)):
            self.probe.create_subscription(kind, topic, self.got[topic].append, LATCHED)
        self.probe.create_subscription(DiagnosticArray, 'diagnostics', self.got['diagnostics'].append, RELIABLE)

    def start(self, **params):
        self.node = TrajectoryNode(context=self.ctx, parameter_overrides=[
            Parameter(k, value=v) for k, v in params.items()])
        self.executor.add_node(self.node)
        self.spin_until(lambda: self.waypoints_pub.get_subscription_count() > 0, 'discovery')
        return self.node

    def wait_for(self, topic, count=1):
        self.spin_until(lambda: len(self.got[topic]) >= count, f'{count} message(s) on {topic}')
        return self.got[topic][-1]

    def wait_for_diagnostic(self, level):
        def found():
            return any(diagnostics.level_of(s) == level[0] for a in self.got['diagnostics'] for s in a.status)
        self.spin_until(found, f'a diagnostics status of level {level}')
        return [s for a in self.got['diagnostics'] for s in a.status if diagnostics.level_of(s) == level[0]][-1]

    def send_waypoints(self, positions, yaw=None):
        msg = Path()
        msg.header.frame_id = 'map'
        for i, p in enumerate(positions):
            pose = PoseStamped()
            pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = map(float, p)
            if yaw is not None:
                pose.pose.orientation.z, pose.pose.orientation.w = np.sin(yaw[i] / 2), np.cos(yaw[i] / 2)
            msg.poses.append(pose)
        self.waypoints_pub.publish(msg)



@pytest.fixture
def graph():
    with probe_graph(Graph) as g:
        yield g


def test_plans_flat_waypoints_at_start_and_publishes_every_output(graph):
    node = graph.start(waypoints=FLAT, start_delay_s=2.0, sample_rate_hz=200.0)
    msg = graph.wait_for('trajectory')
    start_s, sampled = msg_to_sampled(msg)
    assert msg.header.frame_id == 'map'
    assert start_s >= 2.0
    assert np.diff(sampled.times_s).max() == pytest.approx(1 / 200.0)
    np.testing.assert_allclose(sampled.position[0, :3], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(sampled.position[-1, :3], [1, 1, 1.5], atol=1e-9)
    assert sampled.duration_s == pytest.approx(node.result.trajectory.duration_s)
    waypoints = graph.wait_for('trajectory/waypoints')
    assert [[p.pose.position.x, p.pose.position.y, p.pose.position.z] for p in waypoints.poses] == \
        np.reshape(FLAT, (-1, 3)).tolist()
    assert len(graph.wait_for('trajectory/path').poses) > 10
    markers = graph.wait_for('trajectory/markers').markers
    assert markers[0].action == Marker.DELETEALL
    assert [m.type for m in markers if m.ns == 'waypoints'] == [Marker.SPHERE] * 3
    status = graph.wait_for_diagnostic(diagnostics.OK)
    assert status.name == 'trajectory_node: trajectory'
    assert {kv.key: kv.value for kv in status.values}['segments'] == '2'


def test_mission_file_with_world_and_speed_override(graph):
    graph.start(mission_file=DEFAULT_MISSION_PATH, speed_mps=2.0)
    _, sampled = msg_to_sampled(graph.wait_for('trajectory'))
    expected = plan_mission(load_mission(DEFAULT_MISSION_PATH), speed_mps=2.0).trajectory
    assert sampled.duration_s == pytest.approx(expected.duration_s)
    cubes = [m for m in graph.wait_for('trajectory/markers').markers if m.ns == 'obstacles']
    world = load_mission(DEFAULT_MISSION_PATH).world
    assert len(cubes) == len(world.blocks)
    b = world.blocks[0]
    assert (cubes[0].pose.position.x, cubes[0].scale.y) == pytest.approx(((b[0] + b[1]) / 2, b[3] - b[2]))


def test_fleet_vehicle_plans_that_vehicle_of_a_fleet_deconflicted(graph, tmp_path):
    """A fleet bridge graph's trajectory_node (graph.fleet_bridge_graph): one vehicle's plan of a fleet file, with
    the start delay the file's deconfliction gives it (crossing2: cf2 starts 0.5 s later)."""
    import yaml
    data = yaml.safe_load(open(CROSSING))
    data['vehicle'] = os.path.join(os.path.dirname(CROSSING), data['vehicle'])
    data['separation']['deconflict'] = 'delays'
    fleet = tmp_path / 'crossing.yaml'
    fleet.write_text(yaml.safe_dump(data))
    before_ns = time.time_ns()   # the node's clock is the system clock: it plans after this, stamps before `after`
    node = graph.start(mission_file=str(fleet), fleet_vehicle='cf2')
    msg = graph.wait_for('trajectory')
    after_ns = node.get_clock().now().nanoseconds
    _, sampled = msg_to_sampled(msg)
    np.testing.assert_allclose(sampled.position[0, :3], [-2.0, 0.0, 1.0], atol=1e-9)
    np.testing.assert_allclose(sampled.position[-1, :3], [2.0, 0.0, 1.0], atol=1e-9)
    assert node.fleet_delay_s == 0.5
    stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
    assert before_ns + 1_500_000_000 <= stamp_ns <= after_ns + 1_500_000_000   # planned + start_delay_s 1.0 + 0.5


def test_replans_on_a_path_and_refuses_a_bad_one_keeping_the_previous(graph):
    graph.start(waypoints=FLAT)
    first = graph.wait_for('trajectory')
    graph.send_waypoints([[0, 0, 1], [2, 0, 1], [2, 2, 1], [0, 2, 1.2]], yaw=[0.0, 1.0, 2.0, 3.0])
    second = graph.wait_for('trajectory', 2)
    _, sampled = msg_to_sampled(second)
    np.testing.assert_allclose(sampled.position[-1], [0, 2, 1.2, 3.0], atol=1e-6)
    assert stamp_to_s(second.header.stamp) >= stamp_to_s(first.header.stamp)
    assert len(graph.wait_for('trajectory/waypoints', 2).poses) == 4

    graph.send_waypoints([[0, 0, 1], [0, 0, 1.0002]])       # one distinct waypoint: refused
    status = graph.wait_for_diagnostic(diagnostics.ERROR)
    assert 'at least two distinct' in status.message
    graph.send_waypoints([[0, 0, 1], [1, 0, 1]])            # the next good request is planned again
    graph.wait_for('trajectory', 3)
    assert len(graph.got['trajectory']) == 3                # the refused request published nothing


def test_merged_waypoints_are_reported_and_not_planned_through_twice(graph):
    node = graph.start(waypoints=[0.0, 0.0, 1.0, 0.0, 0.0, 1.0005, 1.0, 0.0, 1.0])
    waypoints = graph.wait_for('trajectory/waypoints')
    assert len(waypoints.poses) == 2
    assert node.result.merged[0].index == 1
    status = graph.wait_for_diagnostic(diagnostics.OK)
    assert {kv.key: kv.value for kv in status.values}['merged_waypoints'] == '1'


def test_parameter_change_replans_and_bad_value_is_refused(graph):
    node = graph.start(waypoints=FLAT)
    graph.wait_for('trajectory')
    bad = node.set_parameters([Parameter('method', value='minpop')])[0]
    assert not bad.successful and 'minpop' in bad.reason
    good = node.set_parameters([Parameter('speed_mps', value=1.0)])[0]
    assert good.successful
    _, sampled = msg_to_sampled(graph.wait_for('trajectory', 2))
    assert sampled.duration_s == pytest.approx(node.result.trajectory.duration_s)
    assert node.result.options.speed_mps == 1.0


@pytest.mark.parametrize('args,words', [
    (['-p', 'method:=minpop'], "method = 'minpop'"),
    (['-p', 'waypoints:=[0.0, 0.0, 1.0, 1.0]'], 'multiple of 3'),
    (['-p', 'mission_file:=/nonexistent/m.yaml'], "mission_file = '/nonexistent/m.yaml': /nonexistent/m.yaml: no such"),
    (['-p', 'waypoints:=[0.0, 0.0, 1.0, 0.0, 0.0, 1.0]'], 'at least two distinct'),
    (['-p', f'mission_file:={FORMATION}'], 'is a fleet mission: set fleet_vehicle to the vehicle to plan (cf1, cf2'),
    (['-p', f'mission_file:={FORMATION}', '-p', 'fleet_vehicle:=cf9'], "fleet_vehicle = 'cf9' is not one of"),
    (['-p', f'mission_file:={DEFAULT_MISSION_PATH}', '-p', 'fleet_vehicle:=cf1'], 'is not a fleet mission'),
])
def test_bad_start_up_parameters_exit_2_naming_the_field(args, words):
    with isolated_domain() as (_, env):
        pkg_root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        env = dict(env, PYTHONPATH=os.pathsep.join([pkg_root, env.get('PYTHONPATH', '')]))
        proc = subprocess.run([sys.executable, '-m', 'quad_trajectory.trajectory_node', '--ros-args', *args],
                              env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert words in proc.stderr + proc.stdout


def test_with_sim_time_the_plan_waits_for_the_first_clock(graph):
    """Under use_sim_time the node planned before the first /clock and stamped the plan 0 + 1 s, in the
    past once simulated time arrived (refused by the controller's start-step guard). It now plans at start (a bad
    request still fails at once) and publishes, stamped clock + start_delay_s, when time exists."""
    from rosgraph_msgs.msg import Clock

    from quad_common.conversions import s_to_stamp

    clock_pub = graph.probe.create_publisher(Clock, '/clock', RELIABLE)
    node = graph.start(use_sim_time=True, waypoints=FLAT, start_delay_s=1.0)
    assert node.unpublished is not None and not graph.got['trajectory']   # planned, nothing stamped yet
    graph.spin_until(lambda: clock_pub.get_subscription_count() > 0, 'the node\'s /clock subscription')
    clock_pub.publish(Clock(clock=s_to_stamp(5.0)))
    msg = graph.wait_for('trajectory')
    assert stamp_to_s(msg.header.stamp) == pytest.approx(6.0)
    assert node.unpublished is None and node.clock_wait is None


def test_the_plan_starts_start_delay_after_it_is_published_however_long_its_message_took(graph, monkeypatch):
    """On a busy machine building a long plan's message took seconds; a plan stamped before that arrived already
    started (the controller then joins it mid-way). Here building it takes 1.5 s, the delay is 2 s."""
    build = trajectory_node.sampled_to_trajectory

    def slow_build(*args, **kwargs):
        time.sleep(1.5)   # stands for a starved process, not a synchronisation
        return build(*args, **kwargs)

    monkeypatch.setattr(trajectory_node, 'sampled_to_trajectory', slow_build)
    published = []   # when the plan goes out (not when the probe hears it: discovery on a busy machine adds to that)
    publish = Publisher.publish

    def timed_publish(self, msg):
        if self.msg_type is MultiDOFJointTrajectory:
            published.append(time.time())
        return publish(self, msg)

    monkeypatch.setattr(Publisher, 'publish', timed_publish)
    graph.start(waypoints=FLAT, start_delay_s=2.0)
    msg = graph.wait_for('trajectory')
    start_s, _ = msg_to_sampled(msg)
    assert start_s - published[0] > 1.5, f'the plan starts {start_s - published[0]:.3f} s after it went out'
    path, markers = graph.wait_for('trajectory/path'), graph.wait_for('trajectory/markers')
    assert {(p.header.stamp.sec, p.header.stamp.nanosec) for p in [path, *path.poses, *markers.markers]} == \
        {(msg.header.stamp.sec, msg.header.stamp.nanosec)}
