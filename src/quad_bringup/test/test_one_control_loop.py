"""One control loop: the same mission flown through position_controller in a real rclpy graph (lockstep, the
test playing the simulator as sim_node does: odom then /clock at t_k, wait for the setpoint stamped t_k, advance)
and by the offline loop (quad_bringup.offline.closed_loop) gives the same setpoints to float precision, hold before the
plan, plan start and the pid integral's dt included. The offline loop imports without any ROS package."""

import subprocess
import sys

import numpy as np
import pytest
import rclpy
from nav_msgs.msg import Odometry
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu
from std_msgs.msg import Bool
from trajectory_msgs.msg import MultiDOFJointTrajectory

from quad_bringup.offline.closed_loop import LoopOptions, make_simulator, plan_offline, run_offline
from quad_common import conversions as conv
from quad_common.paths import resolve_config
from quad_common.ros import cdr
from quad_common.ros.testing import isolated_domain
from quad_control.position_controller_node import PositionControllerNode

MISSION = resolve_config('config/missions/stop_every_waypoint.yaml')
OPTIONS = LoopOptions(controller='pid', speed_mps=1.0, start_delay_s=0.3)
TICKS = 250  # 0.3 s of hold, then 2.2 s of the plan
TIMEOUT_S = 60.0
T0_NS = 1_000_000_000
RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def _fly_through_the_node(ctx):
    mission, _, trajectory = plan_offline(MISSION, OPTIONS)
    sim = make_simulator(mission, trajectory, OPTIONS)
    executor = SingleThreadedExecutor(context=ctx)
    probe = rclpy.create_node('sim_probe', context=ctx)
    odom_pub = probe.create_publisher(Odometry, 'odom', RELIABLE)
    clock_pub = probe.create_publisher(Clock, '/clock', RELIABLE)
    traj_pub = probe.create_publisher(MultiDOFJointTrajectory, 'trajectory', LATCHED)
    probe.create_publisher(Bool, 'vehicle/engaged', LATCHED).publish(Bool(data=True))  # as sim_node does
    setpoints = {}
    probe.create_subscription(Imu, 'cmd/attitude_thrust', lambda m: setpoints.setdefault(
        m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec, m), RELIABLE)
    node = PositionControllerNode(context=ctx, parameter_overrides=[
        Parameter('use_sim_time', value=True), Parameter('lockstep', value=True),
        Parameter('wait_for_trajectory', value=True), Parameter('controller', value=OPTIONS.controller),
        Parameter('rate_hz', value=OPTIONS.rate_hz)])
    executor.add_node(probe)
    executor.add_node(node)
    def spin_until(condition, what):
        deadline = probe.get_clock().now().nanoseconds + int(TIMEOUT_S * 1e9)
        while not condition():
            assert probe.get_clock().now().nanoseconds < deadline, f'timed out waiting for {what}'
            executor.spin_once(timeout_sec=0.02)

    try:
        spin_until(lambda: odom_pub.get_subscription_count() and clock_pub.get_subscription_count()
                   and traj_pub.get_subscription_count() and probe.count_publishers('cmd/attitude_thrust'),
                   'discovery')
        packer, period_ns, out = cdr.OdometryPacker(), round(1e9 / OPTIONS.rate_hz), []
        # the graph's time is the offline loop's plus T0 (a sim-time timer does not tick at t = 0)
        traj_pub.publish(conv.sampled_to_msg(trajectory, conv.s_to_stamp(T0_NS * 1e-9 + OPTIONS.start_delay_s)))
        spin_until(lambda: node.trajectory is not None, 'the plan')
        for k in range(TICKS):
            t_ns = T0_NS + k * period_ns
            odom_pub.publish(packer.pack(sim.odometry_state(), t_ns))
            clock_pub.publish(Clock(clock=conv.s_to_stamp(t_ns * 1e-9)))
            if k == 0:  # sim_node republishes its first step until a setpoint comes (the clock was not running)
                spin_until(lambda: node.get_clock().now().nanoseconds == T0_NS, 'the clock')
                odom_pub.publish(packer.pack(sim.odometry_state(), t_ns))
            spin_until(lambda: t_ns in setpoints, f'setpoint at {t_ns * 1e-9:.2f} s')  # noqa: B023
            setpoint = conv.imu_to_setpoint(setpoints[t_ns])
            out.append(setpoint)
            sim.set_setpoint(setpoint)
            sim.advance(period_ns * 1e-9)
        return out, node.counts
    finally:
        for n in (node, probe):
            executor.remove_node(n)
            n.destroy_node()
        executor.shutdown()


@pytest.fixture
def ctx():
    with isolated_domain() as (domain, _):
        context = rclpy.Context()
        rclpy.init(context=context, domain_id=domain)
        try:
            yield context
        finally:
            rclpy.shutdown(context=context)


def _arrays(setpoints):
    return (np.array([s.quaternion for s in setpoints]), np.array([s.specific_force_mps2 for s in setpoints]),
            np.array([s.body_rates for s in setpoints]))


def test_node_and_offline_loop_give_the_same_setpoints(ctx):
    offline = run_offline(MISSION, OPTIONS)
    graph, counts = _fly_through_the_node(ctx)
    for a, b in zip(_arrays(graph), _arrays(offline.setpoints[:TICKS])):
        assert np.allclose(a, b, rtol=0.0, atol=1e-9), np.max(np.abs(a - b))
    # the mission exercised what the loop owns: a hold before the plan, then the plan (with the pid integral)
    held = [r.position for r in offline.references[:30]]
    assert np.allclose(held, held[0]) and offline.loop.counts['refused_start_steps'] == 0
    assert not np.allclose(offline.references[TICKS - 1].position, held[0])
    assert np.any(offline.loop.controller.integral_m_s != 0.0)
    assert counts['setpoints'] == TICKS


def test_offline_loop_imports_without_ros():
    """quad_bringup.offline.closed_loop with every ROS package made unimportable (rclpy, *_msgs, rosbags)."""
    code = ('import sys\n'
            'class Block:\n'
            '    def find_spec(self, name, path=None, target=None):\n'
            '        root = name.split(".")[0]\n'
            '        if root in ("rclpy", "rosbags", "rosidl_runtime_py", "builtin_interfaces") '
            'or root.endswith("_msgs"):\n'
            '            raise ImportError(f"ROS package {name} imported")\n'
            'sys.meta_path.insert(0, Block())\n'
            'import quad_bringup.offline.closed_loop\n'
            'print("ok")\n')
    proc = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and 'ok' in proc.stdout, proc.stderr
