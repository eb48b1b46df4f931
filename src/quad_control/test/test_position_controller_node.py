"""position_controller in a real rclpy graph (DDS, own domain), driven by a test node.

Everything waits on messages or conditions, never on elapsed time.
"""

import math
import subprocess
import sys
import threading

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu
from std_msgs.msg import Bool
from trajectory_msgs.msg import MultiDOFJointTrajectory

from quad_common import conversions as conv
from quad_common import diagnostics
from quad_common.ros.testing import TIMEOUT_S, ProbeGraph, isolated_domain, probe_graph
from quad_common.sampled_trajectory import SampledTrajectory
from quad_common.types import GRAVITY_MPS2, State
from quad_control.position_controller_node import PositionControllerNode

MASS_KG = 0.030  # config/vehicles/crazyflie.yaml
RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


class Graph(ProbeGraph):
    """The controller under test plus a probe node publishing odom, /clock, trajectory and recording outputs."""

    def __init__(self, ctx):
        super().__init__(ctx)
        self.odom_pub = self.probe.create_publisher(Odometry, 'odom', RELIABLE)
        self.clock_pub = self.probe.create_publisher(Clock, '/clock', RELIABLE)
        self.traj_pub = self.probe.create_publisher(MultiDOFJointTrajectory, 'trajectory', LATCHED)
        self.engaged_pub = self.probe.create_publisher(Bool, 'vehicle/engaged', LATCHED)
        self.setpoints, self.diags, self.references = [], [], []
        self.probe.create_subscription(Imu, 'cmd/attitude_thrust', self.setpoints.append, RELIABLE)
        self.probe.create_subscription(MultiDOFJointTrajectory, 'control/reference', self.references.append, RELIABLE)
        self.probe.create_subscription(DiagnosticArray, 'diagnostics', self.diags.append, RELIABLE)

    def start(self, engaged=True, **params):
        """The controller with `params`; engaged: vehicle/engaged is published true first (as a simulator does)."""
        if engaged:
            self.engaged_pub.publish(Bool(data=True))
        self.node = PositionControllerNode(context=self.ctx, parameter_overrides=[
            Parameter(k, value=v) for k, v in params.items()])
        self.executor.add_node(self.node)
        self.spin_until(lambda: self.odom_pub.get_subscription_count() > 0
                        and (self.clock_pub.get_subscription_count() > 0 or not params.get('use_sim_time'))
                        and len(self.probe.get_publishers_info_by_topic('/cmd/attitude_thrust')) > 0
                        and self.node.loop.engaged == (engaged or not params.get('wait_for_engagement', True)),
                        'discovery')
        return self.node

    def engage(self, engaged):
        self.engaged_pub.publish(Bool(data=engaged))
        self.spin_until(lambda: self.node.loop.engaged == engaged, f'engaged {engaged}')

    def step(self, t_s, **odom):
        """One simulator step: odom then /clock at t_s; returns the reference position tracked at t_s."""
        if not self.node.loop.lockstep:   # the tick runs on the /clock: it must find this odometry taken, and
            self.publish_clock(t_s - 0.005)  # odometry more than a period ahead of the clock is refused
            stamp_ns = round(t_s * 1e9)
            self.publish_odom(t_s, **odom)
            self.spin_until(lambda: self.node.loop.odom is not None and self.node.loop.odom[0] == stamp_ns, 'odom')
        else:
            self.publish_odom(t_s, **odom)
        self.publish_clock(t_s)
        stamp = conv.s_to_stamp(t_s)
        self.spin_until(lambda: any(m.header.stamp == stamp for m in self.references), f'reference at {t_s}')
        [ref] = [m for m in self.references if m.header.stamp == stamp]
        return conv.vec3(ref.points[0].transforms[0].translation)

    def publish_odom(self, t_s, z=1.0, x=0.0):
        state = State(position=np.array([x, 0.0, z]))
        self.odom_pub.publish(conv.state_to_odometry(state, conv.s_to_stamp(t_s)))

    def odom_until(self, condition, what, **odom):
        """publish_odom(0.0, **odom) until condition(): a stalled machine can call the odometry stale before a tick
        took it (odom_timeout_s is wall time), and then nothing else would come."""
        self.spin_until(lambda: condition() or self.publish_odom(0.0, **odom), what)

    def publish_clock(self, t_s):
        self.clock_pub.publish(Clock(clock=conv.s_to_stamp(t_s)))

    def setpoints_at(self, t_s):
        return [m for m in self.setpoints if m.header.stamp == conv.s_to_stamp(t_s)]

    def node_status(self):
        n = len(self.diags)
        self.node.publish_diagnostics()
        self.spin_until(lambda: len(self.diags) > n, 'diagnostics')
        return _status(self.diags[-1])



@pytest.fixture
def graph():
    with probe_graph(Graph) as g:
        yield g


def _hover_trajectory(z_m):
    """A latched trajectory holding (0, 0, z_m), started at t = 0."""
    p = np.array([[0.0, 0.0, z_m, 0.0]] * 2)
    return conv.sampled_to_msg(SampledTrajectory([0.0, 100.0], p, np.zeros((2, 4)), np.zeros((2, 4))),
                               conv.s_to_stamp(0.0))


def _thrust(msg):
    return msg.linear_acceleration.z * MASS_KG


def _status(diag_msg):
    return diag_msg.status[0]


def test_lockstep_tick_waits_for_its_odometry(graph):
    graph.start(use_sim_time=True, lockstep=True, rate_hz=100.0)
    graph.traj_pub.publish(_hover_trajectory(1.0))
    graph.spin_until(lambda: graph.node.trajectory is not None, 'trajectory')
    # t = 1.00: odom then clock, as the simulator does
    graph.publish_odom(1.00, z=0.9)
    graph.publish_clock(1.00)
    graph.spin_until(lambda: graph.setpoints_at(1.00), 'setpoint at 1.00')
    # t = 1.01: the clock comes first; the tick must wait for the odometry stamped 1.01
    graph.publish_clock(1.01)
    graph.spin_until(lambda: graph.node.pending_tick_ns == 1_010_000_000, 'deferred tick')
    assert not graph.setpoints_at(1.01)
    graph.publish_odom(1.01, z=0.8)
    graph.spin_until(lambda: graph.setpoints_at(1.01), 'setpoint at 1.01')
    # a third step as a barrier: everything stamped 1.01 has arrived before it
    graph.publish_odom(1.02, z=0.95)
    graph.publish_clock(1.02)
    graph.spin_until(lambda: graph.setpoints_at(1.02), 'setpoint at 1.02')
    # eq. 2 with kp_z 20, zero velocity: u1 = m (g + 20 (1 - z))
    for t_s, z in ((1.00, 0.9), (1.01, 0.8), (1.02, 0.95)):
        [sp] = graph.setpoints_at(t_s)
        assert math.isclose(_thrust(sp), MASS_KG * (GRAVITY_MPS2 + 20.0 * (1.0 - z)), rel_tol=1e-9)
    assert graph.node.counts['deferred_ticks'] >= 1


def test_holds_before_start_tracks_then_holds_final_point(graph):
    graph.start(use_sim_time=True, lockstep=True)
    assert np.allclose(graph.step(1.0, x=0.3, z=0.7), [0.3, 0, 0.7])      # no trajectory: where it is
    p = np.array([[0.0, 0.0, 1.0, 0.0], [1.0, 0.0, 1.0, 0.0]])
    graph.traj_pub.publish(conv.sampled_to_msg(SampledTrajectory([0.0, 1.0], p, np.zeros((2, 4)), np.zeros((2, 4))),
                                               conv.s_to_stamp(2.0)))
    graph.spin_until(lambda: graph.node.trajectory is not None, 'trajectory')
    assert np.allclose(graph.step(1.5, x=0.0, z=1.0), [0.3, 0, 0.7])      # not started: still the hold point
    assert np.allclose(graph.step(2.5), [0.5, 0, 1.0])                    # the quintic's midpoint
    assert np.allclose(graph.step(4.0), [1.0, 0, 1.0])                    # after the end: the final point
    values = {kv.key: kv.value for kv in graph.node_status().values}
    assert values['mode'] == 'hold (trajectory ended)'


def test_nonfinite_odometry_stops_setpoints_and_resumes(graph):
    graph.start(lockstep=True, rate_hz=100.0, use_sim_time=True)
    graph.publish_odom(0.5)
    graph.publish_clock(0.5)
    graph.spin_until(lambda: graph.setpoints_at(0.5), 'first setpoint')
    graph.publish_odom(0.51, z=math.nan)
    graph.publish_clock(0.51)
    graph.spin_until(lambda: any(_status(d).level == diagnostics.ERROR
                                 and 'non-finite' in _status(d).message for d in graph.diags), 'ERROR')
    graph.spin_until(lambda: graph.node.pending_tick_ns == 510_000_000, 'tick 0.51 waiting')
    assert not graph.setpoints_at(0.51)
    # a finite odometry for the same time: the setpoint comes, computed from it, and finite
    graph.publish_odom(0.51, z=0.9)
    graph.spin_until(lambda: graph.setpoints_at(0.51), 'setpoint after recovery')
    [sp] = graph.setpoints_at(0.51)
    assert math.isclose(_thrust(sp), MASS_KG * (GRAVITY_MPS2 + 20.0 * 0.1), rel_tol=1e-9)
    assert all(np.isfinite(m.linear_acceleration.z) for m in graph.setpoints)
    assert graph.node.counts['nonfinite_odom'] == 1
    graph.node.publish_diagnostics()
    graph.spin_until(lambda: _status(graph.diags[-1]).level == diagnostics.OK, 'OK again')


def test_nonfinite_trajectory_is_refused_and_the_previous_kept(graph):
    graph.start(use_sim_time=True, lockstep=True)
    graph.traj_pub.publish(_hover_trajectory(1.0))
    graph.spin_until(lambda: graph.node.trajectory is not None, 'trajectory')
    kept = graph.node.trajectory
    bad = _hover_trajectory(2.0)
    bad.points[1].accelerations[0].linear.x = math.nan
    graph.traj_pub.publish(bad)
    graph.spin_until(lambda: graph.node.counts['rejected_trajectories'] == 1, 'refusal')
    assert graph.node.trajectory is kept
    graph.spin_until(lambda: any(_status(d).level == diagnostics.ERROR and 'trajectory refused' in _status(d).message
                                 for d in graph.diags), 'ERROR naming the refusal')
    assert np.allclose(graph.step(3.0, z=0.9), [0, 0, 1.0])  # still flying the first one


def test_stale_odometry_stops_setpoints_then_resumes(graph):
    graph.start(odom_timeout_s=0.2, rate_hz=100.0)
    graph.odom_until(lambda: len(graph.setpoints) > 0, 'setpoints with fresh odom')
    graph.spin_until(lambda: not graph.node.stale, 'fresh')
    before = graph.node.counts['odom_timeouts']   # a stalled start may have counted one already
    # no more odometry: after 0.2 s the node stops and reports ERROR
    graph.spin_until(lambda: any(_status(d).level == diagnostics.ERROR
                                 and 'stale' in _status(d).message for d in graph.diags), 'stale ERROR')
    stale_at = max(conv.stamp_to_s(d.header.stamp) for d in graph.diags
                   if 'stale' in _status(d).message)
    assert graph.node.counts['odom_timeouts'] == before + 1
    n_diags = len(graph.diags)
    graph.spin_until(lambda: len(graph.diags) >= n_diags + 2, 'two more diagnostics')
    assert _status(graph.diags[-1]).level == diagnostics.ERROR
    assert not [m for m in graph.setpoints if conv.stamp_to_s(m.header.stamp) > stale_at]
    assert graph.node.counts['odom_timeouts'] == before + 1
    # odometry returns: setpoints resume, diagnostics OK
    n_before = len(graph.setpoints)
    graph.odom_until(lambda: len(graph.setpoints) > n_before, 'setpoints resume')
    graph.node.publish_diagnostics()
    graph.spin_until(lambda: _status(graph.diags[-1]).level == diagnostics.OK, 'OK again')
    values = {kv.key: kv.value for kv in _status(graph.diags[-1]).values}
    assert values['controller'] == 'pd' and values['odom_timeouts'] == str(graph.node.counts['odom_timeouts'])


def test_odometry_waiting_in_the_subscription_is_not_stale(graph):
    """A process that was not scheduled for longer than odom_timeout_s finds
    its timer and a new odometry ready at once; the tick takes that odometry before judging staleness (on a loaded
    2-core machine the tick used to run first and stop the setpoints although odometry was there)."""
    node = graph.start(odom_timeout_s=0.2, rate_hz=100.0)
    graph.publish_odom(0.0)
    graph.spin_until(lambda: len(graph.setpoints) > 0, 'setpoints with fresh odom')
    graph.executor.remove_node(node)               # the node is not scheduled from here on ...
    node.odom_received_ns -= 1_000_000_000          # ... for a second, as far as its odometry age goes
    graph.publish_odom(0.0, z=0.9)
    waiting = _rclpy.WaitSet(1, 0, 0, 0, 0, 0, graph.ctx.handle)
    waiting.add_subscription(node.state_sub.handle)
    waiting.wait(int(TIMEOUT_S * 1e9))               # the odometry is in the node's subscription, not yet taken
    assert node.state_sub.handle.pointer in waiting.get_ready_entities('subscription')
    n = len(graph.setpoints)
    node._on_tick()                                  # the timer runs first
    assert node.counts['odom_timeouts'] == 0 and node.loop.odom[1].position[2] == 0.9
    graph.spin_until(lambda: len(graph.setpoints) > n, 'the tick\'s setpoint')
    graph.executor.add_node(node)


def test_bad_runtime_parameters_are_refused_and_good_ones_apply(graph):
    node = graph.start()
    for name, value in (('kp_x', -1.0), ('kd_y', math.nan), ('rate_hz', 0.0), ('controller', 'lqr'),
                        ('max_tilt_deg', 95.0)):
        old = node.params[name]
        result = node.set_parameters([Parameter(name, value=value)])[0]
        assert not result.successful and name in result.reason and repr(value) in result.reason
        assert node.params[name] == old
    assert node.set_parameters([Parameter('kp_y', value=7.5)])[0].successful
    assert node.controller.gains.kp.tolist() == [5.0, 7.5, 20.0]
    assert node.set_parameters([Parameter('controller', value='se3')])[0].successful
    assert node.controller.name == 'se3'
    assert node.set_parameters([Parameter('rate_hz', value=250.0)])[0].successful
    assert math.isclose(node.timer.timer_period_ns, 4e6)


def test_invalid_startup_parameter_exits_2_naming_it():
    with isolated_domain() as (_, env):
        proc = subprocess.run([sys.executable, '-m', 'quad_control.position_controller_node', '--ros-args',
                               '-p', 'kp_z:=-3.0'], env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert 'kp_z' in proc.stderr + proc.stdout and '-3.0' in proc.stderr + proc.stdout


def _line_trajectory(start_xyz, start_s):
    """A 1 s line from start_xyz, 0.5 m along x, latched, starting at start_s."""
    p0 = np.array([*start_xyz, 0.0])
    p = np.array([p0, p0 + [0.5, 0.0, 0.0, 0.0]])
    return conv.sampled_to_msg(SampledTrajectory([0.0, 1.0], p, np.zeros((2, 4)), np.zeros((2, 4))),
                               conv.s_to_stamp(start_s))


def test_plan_starting_away_from_the_vehicle_is_refused_and_held(graph):
    """A plan whose start is 1.5 m from where the vehicle hovers is not flown as a step."""
    graph.start(use_sim_time=True, lockstep=True, max_start_step_m=0.5)
    assert np.allclose(graph.step(1.0, z=1.0), [0, 0, 1.0])
    graph.traj_pub.publish(_line_trajectory([1.5, 0.0, 1.0], 2.0))
    graph.spin_until(lambda: graph.node.trajectory is not None, 'trajectory')
    assert np.allclose(graph.step(1.5, z=1.0), [0, 0, 1.0])
    assert np.allclose(graph.step(2.0, z=1.0), [0, 0, 1.0])   # its start: refused, still the hold point
    assert np.allclose(graph.step(2.5, z=1.0), [0, 0, 1.0])
    graph.spin_until(lambda: any('max_start_step_m' in _status(d).message for d in graph.diags), 'the refusal')
    refusal = next(_status(d) for d in graph.diags if 'max_start_step_m' in _status(d).message)
    assert refusal.level == diagnostics.ERROR and '1.500 m' in refusal.message
    values = {kv.key: kv.value for kv in graph.node_status().values}
    assert values['refused_start_steps'] == '1' and math.isclose(float(values['start_step_m']), 1.5)
    assert values['mode'] == 'hold (no trajectory)'
    # a plan that starts where the vehicle is, is taken
    graph.traj_pub.publish(_line_trajectory([0.1, 0.0, 1.0], 3.0))
    graph.spin_until(lambda: graph.node.trajectory is not None and graph.node.trajectory.start_ns == 3_000_000_000,
                     'the second plan')
    assert np.allclose(graph.step(3.5, z=1.0), [0.35, 0, 1.0])
    assert graph.node.counts['refused_start_steps'] == 1


def test_hold_point_is_not_re_anchored_after_stale_odometry(graph):
    """After a stale-odometry event the hold point stays where it was anchored (it used to move to
    wherever the vehicle had drifted)."""
    graph.start(odom_timeout_s=0.2, rate_hz=100.0)
    graph.odom_until(lambda: len(graph.references) > 0, 'references with fresh odom', x=0.0, z=1.0)
    graph.spin_until(lambda: graph.node.stale, 'stale')
    n = len(graph.references)
    # the vehicle drifted while odometry was stale (published until it is taken: a stall can make it stale again)
    graph.odom_until(lambda: len(graph.references) > n + 3, 'references again', x=0.8, z=0.6)
    for ref in graph.references:
        assert np.allclose(conv.vec3(ref.points[0].transforms[0].translation), [0.0, 0.0, 1.0])
    values = {kv.key: kv.value for kv in graph.node_status().values}
    assert values['hold_position_m'] == '[0.0, 0.0, 1.0]'


def test_ticks_go_on_while_a_trajectory_is_decoded(graph):
    """The tick never waits for a trajectory. The decode is held (an Event) while the lockstep graph
    steps on: setpoints keep coming from the hold point; once released, the plan is swapped in between ticks."""
    graph.start(use_sim_time=True, lockstep=True)
    release, decoding = threading.Event(), threading.Event()
    decode = graph.node.trajectory_decoder.decode

    def held_decode(raw):
        decoding.set()
        assert release.wait(TIMEOUT_S)
        return decode(raw)

    graph.node.trajectory_decoder.decode = held_decode
    assert np.allclose(graph.step(1.0, z=0.9), [0, 0, 0.9])
    graph.traj_pub.publish(_line_trajectory([0.0, 0.0, 0.9], 1.0))
    graph.spin_until(decoding.is_set, 'the decode to begin')
    for k in range(1, 6):  # the decode is still running: ticks are not blocked
        assert np.allclose(graph.step(1.0 + 0.01 * k, z=0.9), [0, 0, 0.9])
    assert graph.node.trajectory is None
    release.set()
    graph.spin_until(lambda: graph.node.trajectory is not None, 'the plan swapped in')
    assert np.allclose(graph.step(1.5, z=0.9), [0.25, 0, 0.9])


def test_odometry_from_the_future_is_refused_and_a_later_valid_one_applied(graph):
    """Odometry stamped beyond one period ahead of the node clock is
    refused, counted and named in diagnostics; it does not become the newest odometry a lockstep tick runs on."""
    graph.start(use_sim_time=True, lockstep=True, rate_hz=100.0)
    graph.step(1.0, z=1.0)
    graph.publish_odom(5.0, z=0.5)        # a node on another clock, far ahead
    graph.spin_until(lambda: graph.node.counts['future_odom'] == 1, 'the refusal')
    graph.publish_clock(1.01)             # the tick at 1.01 must wait for the odometry stamped 1.01 ...
    graph.spin_until(lambda: graph.node.pending_tick_ns == 1_010_000_000, 'the tick at 1.01 deferred')
    graph.publish_odom(1.01, z=0.9)       # ... and run with it
    graph.spin_until(lambda: graph.setpoints_at(1.01), 'setpoint at 1.01')
    [sp] = graph.setpoints_at(1.01)
    assert math.isclose(_thrust(sp), MASS_KG * (GRAVITY_MPS2 + 20.0 * 0.1), rel_tol=1e-9)
    graph.publish_odom(1.02, z=1.0)       # one period ahead of the clock (the simulator's order): accepted
    graph.publish_clock(1.02)
    graph.spin_until(lambda: graph.setpoints_at(1.02), 'setpoint at 1.02')
    values = {kv.key: kv.value for kv in graph.node_status().values}
    assert values['future_odom'] == '1'
    assert 'stamp 5.000000 s > clock 1.0' in values['last_future_odom']


def test_plan_runs_only_while_engaged_and_starts_from_the_vehicle(graph):
    """Before the hand-over the setpoints hover where the vehicle is and the plan's clock does not run;
    at engagement the controller holds where the vehicle is and a plan whose stamp has passed begins its own
    start delay later; the end of the hand-over pauses it, the next engagement resumes it from there. Not lockstep:
    a bridge's controller ticks before the hand-over (lockstep ticks wait for the simulator's engagement)."""
    graph.start(engaged=False, use_sim_time=True, lockstep=False, odom_timeout_s=10.0)
    assert np.allclose(graph.step(1.0, x=0.3, z=0.7), [0.3, 0, 0.7])       # not engaged: where the vehicle is
    graph.traj_pub.publish(_line_trajectory([0.0, 0.0, 1.0], 2.0))        # received at 1.0: its start delay 1 s
    graph.spin_until(lambda: graph.node.trajectory is not None, 'trajectory')
    assert np.allclose(graph.step(2.5, x=0.0, z=1.0), [0.0, 0, 1.0])      # its stamp passed: it does not run
    assert np.allclose(graph.step(3.0, x=0.05, z=1.0), [0.05, 0, 1.0])    # still following the vehicle
    graph.engage(True)                                                      # engaged at 3.0: plan at 4.0
    assert np.allclose(graph.step(3.5, x=0.0, z=1.0), [0.05, 0, 1.0])     # hold, anchored where it was at 3.0
    assert np.allclose(graph.step(3.9, x=0.2, z=1.1), [0.05, 0, 1.0])     # ... and not re-anchored
    assert np.allclose(graph.step(4.5, x=0.0, z=1.0), [0.25, 0, 1.0])     # the plan's midpoint, 0.5 s in
    graph.engage(False)                                                     # paused at 0.5 s of 1 s
    values = {kv.key: kv.value for kv in graph.node_status().values}
    assert values['engaged'] == 'False' and values['mode'].startswith('not engaged')
    assert np.allclose(graph.step(5.0, x=0.3, z=1.0), [0.3, 0, 1.0])
    assert np.allclose(graph.step(5.5, x=0.3, z=1.0), [0.3, 0, 1.0])
    graph.engage(True)                                                      # at 5.5: resumes at 6.5
    assert np.allclose(graph.step(6.0, x=0.25, z=1.0), [0.3, 0, 1.0])     # held where it was at 5.5
    assert np.allclose(graph.step(6.5, x=0.25, z=1.0), [0.25, 0, 1.0])    # from where it stopped
    assert np.allclose(graph.step(6.75, x=0.25, z=1.0), [0.5 * 0.896484375, 0, 1.0])  # quintic at 0.75
    assert graph.node.counts['refused_start_steps'] == 0


def test_a_plan_arriving_after_an_engagement_it_predates_starts_as_at_that_engagement(graph):
    """A realtime simulator engages at its first setpoint, which may come before the latched plan: a plan whose
    start was before the engagement starts engage_delay_s after it, from the hold (it ran on its stamp: already
    ended, its final point 0.5 m away flown as a step)."""
    graph.start(engaged=False, use_sim_time=True, lockstep=False, odom_timeout_s=10.0)
    graph.step(3.0, x=0.0, z=1.0)
    graph.engage(True)                                                      # at 3.0, nothing to fly yet
    graph.traj_pub.publish(_line_trajectory([0.0, 0.0, 1.0], 2.0))        # starts at 2.0, before the engagement
    graph.spin_until(lambda: graph.node.trajectory is not None, 'trajectory')
    assert np.allclose(graph.step(3.5, x=0.0, z=1.0), [0.0, 0, 1.0])      # holding: the plan starts at 4.0
    assert np.allclose(graph.step(4.5, x=0.0, z=1.0), [0.25, 0, 1.0])     # the plan's midpoint, 0.5 s in
    assert graph.node.counts['refused_start_steps'] == 0


def test_without_wait_for_engagement_a_plan_runs_on_its_stamp(graph):
    """A plant that publishes no engagement (wait_for_engagement false): the plan starts at its stamp."""
    graph.start(engaged=False, use_sim_time=True, lockstep=True, wait_for_engagement=False)
    graph.step(1.0, z=1.0)
    graph.traj_pub.publish(_line_trajectory([0.0, 0.0, 1.0], 2.0))
    graph.spin_until(lambda: graph.node.trajectory is not None, 'trajectory')
    assert np.allclose(graph.step(2.5, z=1.0), [0.25, 0, 1.0])


def test_diagnostics_report_the_mean_age_of_the_odometry_the_setpoints_flew(graph):
    """odom_age_ms: tick time - the odometry's stamp, averaged over the setpoints since the last report (replay's
    twin flies the flight with it); None when no setpoint was published since."""
    graph.start(use_sim_time=True, lockstep=False, odom_timeout_s=10.0)
    graph.publish_clock(0.995)
    graph.publish_odom(0.96)
    graph.spin_until(lambda: graph.node.loop.odom is not None and graph.node.loop.odom[0] == 960_000_000, 'odom')
    graph.node_status()      # the report window starts here
    n = len(graph.references)
    graph.publish_clock(1.0)
    graph.spin_until(lambda: any(m.header.stamp == conv.s_to_stamp(1.0) for m in graph.references), 'tick at 1.0')
    ticks_s = [conv.stamp_to_s(m.header.stamp) for m in graph.references[n:]]
    values = {kv.key: kv.value for kv in graph.node_status().values}
    assert float(values['odom_age_ms']) == pytest.approx(1e3 * (np.mean(ticks_s) - 0.96), abs=1e-3)
    assert float(values['odom_age_ms']) >= 35.0 - 1e-3       # ticks at 0.995 and 1.0 on the odometry of 0.96
    values = {kv.key: kv.value for kv in graph.node_status().values}
    assert values['odom_age_ms'] == 'None'



@pytest.mark.parametrize(('learning_s', 'reported'), [(0.0, 'None'), (20.0, '0.4')])
def test_diagnostics_report_the_drag_learnt(graph, learning_s, reported):
    """drag_learnt_per_s: the learnt D while drag_learning_time_s > 0 (from drag_feedforward_per_s, nothing learnt
    in a hover), None while not learning."""
    graph.start(use_sim_time=True, lockstep=True, drag_feedforward_per_s=0.4, drag_learning_time_s=learning_s)
    graph.step(1.0, z=1.0)
    values = {kv.key: kv.value for kv in graph.node_status().values}
    assert values['drag_learnt_per_s'] == reported

def test_state_source_external_pose_flies_from_motion_capture_with_a_filtered_velocity(graph):
    """state_source external_pose: the controller takes no odometry; each pose on external/pose (Y-up here, as
    Motive streams it) is its state, with the velocity quad_control.pose_state's filter makes of the poses."""
    from geometry_msgs.msg import PoseStamped
    pose_pub = graph.probe.create_publisher(PoseStamped, 'external/pose', RELIABLE)
    graph.engaged_pub.publish(Bool(data=True))
    graph.node = PositionControllerNode(context=graph.ctx, parameter_overrides=[
        Parameter('use_sim_time', value=True), Parameter('lockstep', value=True),
        Parameter('state_source', value='external_pose'), Parameter('external_pose_frame', value='y_up')])
    graph.executor.add_node(graph.node)
    graph.spin_until(lambda: pose_pub.get_subscription_count() > 0 and graph.clock_pub.get_subscription_count() > 0
                     and len(graph.probe.get_publishers_info_by_topic('/cmd/attitude_thrust')) > 0
                     and graph.node.loop.engaged, 'discovery')
    assert graph.odom_pub.get_subscription_count() == 0      # odometry is not its state
    graph.traj_pub.publish(_hover_trajectory(1.0))
    graph.spin_until(lambda: graph.node.trajectory is not None, 'trajectory')
    def pose(t_s):   # ENU x = 0.5 t at 1 m height: Y-up (x, y, z) = (x_enu, z_enu, -y_enu)
        msg = PoseStamped()
        msg.header.stamp = conv.s_to_stamp(t_s)
        msg.pose.position.x, msg.pose.position.y = 0.5 * t_s, 1.0
        msg.pose.orientation.w = 1.0
        return msg

    for k in range(50):
        t_s = 1.0 + 0.01 * k
        pose_pub.publish(pose(t_s))
        graph.publish_clock(t_s)
        graph.spin_until(lambda t_s=t_s: graph.setpoints_at(t_s), f'setpoint at {t_s:.2f}')
    stamp_ns, state = graph.node.loop.odom
    assert stamp_ns == 1_490_000_000
    assert np.allclose(state.position, [0.745, 0.0, 1.0], atol=1e-9)
    assert np.allclose(state.velocity, [0.5, 0.0, 0.0], atol=0.01)   # from poses alone
    # pd (eq. 1): ahead of the plan and moving away from it, the commanded acceleration points back: pitch < 0
    [sp] = graph.setpoints_at(1.49)
    tilt_x = 2.0 * (sp.orientation.w * sp.orientation.y + sp.orientation.x * sp.orientation.z)
    assert tilt_x < 0.0
    assert graph.node.counts['nonfinite_odom'] == 0
    # a pose from the future is refused without entering the filter, and a repeated one is counted and dropped:
    # the next pose in time still flies
    pose_pub.publish(pose(100.0))
    graph.spin_until(lambda: graph.node.counts['future_odom'] == 1, 'the future pose refused')
    pose_pub.publish(pose(1.49))
    graph.spin_until(lambda: graph.node.counts['old_poses'] == 1, 'the repeated pose dropped')
    pose_pub.publish(pose(1.50))
    graph.publish_clock(1.50)
    graph.spin_until(lambda: graph.setpoints_at(1.50), 'setpoint at 1.50')
    assert graph.node.loop.odom[0] == 1_500_000_000
    # a non-finite pose is refused as non-finite odometry is, and leaves the filter as it was
    bad = pose(1.51)
    bad.pose.position.x = math.nan
    pose_pub.publish(bad)
    graph.spin_until(lambda: graph.node.counts['nonfinite_odom'] == 1, 'the non-finite pose refused')
    pose_pub.publish(pose(1.51))
    graph.publish_clock(1.51)
    graph.spin_until(lambda: graph.setpoints_at(1.51), 'setpoint at 1.51')
    assert np.isfinite(graph.node.loop.odom[1].velocity).all()
