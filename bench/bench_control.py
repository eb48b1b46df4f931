"""Control: cost of one position-control update per controller, and the node's achieved loop rate and
period jitter (wall-clock mode) at 100, 250 and 500 Hz. Prints one markdown section."""

import subprocess
import sys
import time
import timeit
from contextlib import contextmanager

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from sensor_msgs.msg import Imu
from trajectory_msgs.msg import MultiDOFJointTrajectory

from quad_common import conversions as conv
from quad_common.domains import isolated_domain
from quad_common.paths import resolve_config
from quad_common.sampled_trajectory import SampledTrajectory
from quad_common.types import Reference, State
from quad_common.vehicle import load_vehicle
from quad_control.position import CONTROLLERS, PositionController, PositionGains

RATES_HZ = (100.0, 250.0, 500.0)
MEASURE_S = 4.0
ARRIVAL_POINTS = 10_000   # a trajectory this long arrives while the node ticks (a large plan must not stall the tick)
ARRIVAL_WINDOW_S = 3.0


def update_cost_us():
    vehicle = load_vehicle(resolve_config('config/vehicles/crazyflie.yaml'))
    state = State(position=np.array([0.1, -0.2, 0.9]), velocity=np.array([0.3, 0.1, 0.0]))
    ref = Reference(position=np.array([0.0, 0.0, 1.0]), acceleration=np.array([0.2, 0.1, 0.0]),
                    jerk=np.array([0.1, 0.0, 0.0]), yaw=0.3, yaw_rate=0.1)
    out = {}
    for name in CONTROLLERS:
        ctl = PositionController(name, PositionGains(), vehicle)
        n = 2000
        best = min(timeit.repeat(lambda: ctl.update(state, ref, 0.01), number=n, repeat=5))  # noqa: B023
        out[name] = best / n * 1e6
    return out


@contextmanager
def controller_node(rate_hz, env, domain, probe_name, odom_period_s):
    """A position_controller process in wall-clock mode at rate_hz, fed hover odometry every odom_period_s by a
    probe node; yields (probe node, its executor, the stamps of cmd/attitude_thrust received so far) and stops
    both on exit."""
    proc = subprocess.Popen([sys.executable, '-m', 'quad_control.position_controller_node', '--ros-args',
                             '-p', f'rate_hz:={rate_hz}', '-p', 'odom_timeout_s:=2.0', '--log-level', 'warn'],
                            env=env)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain)
    node = rclpy.create_node(probe_name, context=ctx)
    stamps = []
    node.create_subscription(Imu, 'cmd/attitude_thrust', lambda m: stamps.append(conv.stamp_to_s(m.header.stamp)),
                             QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE))
    odom_pub = node.create_publisher(Odometry, 'odom', QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    node.create_timer(odom_period_s, lambda: odom_pub.publish(
        conv.state_to_odometry(State(position=np.array([0.0, 0.0, 1.0])), node.get_clock().now().to_msg())))
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    try:
        yield node, executor, stamps
    finally:
        proc.terminate()
        proc.wait(timeout=30)
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=ctx)


def node_timing(rate_hz, env, domain):
    """Stamps of cmd/attitude_thrust (= tick times on the wall clock) over MEASURE_S seconds."""
    with controller_node(rate_hz, env, domain, 'bench_control', 0.02) as (_, executor, stamps):
        deadline = time.monotonic() + 60.0
        while not stamps and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        stamps.clear()
        end = time.monotonic() + MEASURE_S
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
    t = np.sort(np.array(stamps))
    periods = np.diff(t)
    jitter = np.abs(periods - 1.0 / rate_hz)
    return {'achieved_hz': (len(t) - 1) / (t[-1] - t[0]), 'p50_us': np.percentile(jitter, 50) * 1e6,
            'p99_us': np.percentile(jitter, 99) * 1e6, 'max_period_ms': periods.max() * 1e3}


def arrival_gap(env, domain, rate_hz=100.0):
    """Longest period between setpoint stamps (the node's tick times, ms) in the ARRIVAL_WINDOW_S after an
    ARRIVAL_POINTS-point trajectory is published to a node ticking at rate_hz in wall-clock mode, and the longest
    before it (same length). Stamps, not receipt times: publishing 2 MB stalls this probe too."""
    with controller_node(rate_hz, env, domain, 'bench_arrival', 0.01) as (node, executor, stamps):
        traj_pub = node.create_publisher(MultiDOFJointTrajectory, 'trajectory', QoSProfile(
            depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL))
        t = np.arange(ARRIVAL_POINTS) * 0.01
        p = np.column_stack([0.01 * np.sin(t), np.zeros_like(t), np.ones_like(t), np.zeros_like(t)])
        plan = conv.sampled_to_msg(SampledTrajectory(t, p, np.zeros_like(p), np.zeros_like(p)),
                                   (node.get_clock().now() + Duration(seconds=3600)).to_msg())
        # the node's diagnostics say it holds the plan: mode 'hold (trajectory not started)' when engaged, '...,
        # plan waiting' when not (no vehicle/engaged here: it follows the vehicle, and ticks all the same)
        has_plan = []
        node.create_subscription(DiagnosticArray, 'diagnostics', lambda m: has_plan.extend(
            1 for st in m.status for kv in st.values
            if kv.key == 'mode' and ('not started' in kv.value or 'plan waiting' in kv.value)), 10)

        def spin_for(seconds, until=lambda: False):
            end = time.monotonic() + seconds
            while time.monotonic() < end and not until():
                executor.spin_once(timeout_sec=0.005)

        deadline = time.monotonic() + 60.0
        while len(stamps) < 50 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        spin_for(ARRIVAL_WINDOW_S)
        sent = node.get_clock().now().nanoseconds * 1e-9  # the node's clock too (system time)
        traj_pub.publish(plan)
        spin_for(60.0, until=lambda: has_plan)  # the node took it (diagnostics, once a second) ...
        taken = bool(has_plan)
        spin_for(1.0)                           # ... and ticks on
    s = np.sort(np.array(stamps))
    before, after = s[(s >= sent - ARRIVAL_WINDOW_S) & (s < sent)], s[s >= sent]
    if not taken:
        raise RuntimeError('the node did not take the trajectory within 60 s')
    return {'before_ms': np.diff(before).max() * 1e3, 'after_ms': np.diff(np.r_[before[-1:], after]).max() * 1e3,
            'bytes': len(serialize_message(plan))}


def main():
    cost = update_cost_us()
    rows = []
    with isolated_domain() as (domain, env):
        for rate in RATES_HZ:
            rows.append((rate, node_timing(rate, env, domain)))
        arrival = arrival_gap(env, domain)
    print('### Control (quad_control)\n')
    print('One `PositionController.update` (best of 5 x 2000 calls, crazyflie, one core), and the '
          '`position_controller` node in wall-clock mode: setpoint stamps (= tick times) over '
          f'{MEASURE_S:.0f} s, jitter = |period - 1/rate_hz|.\n')
    print('| controller | update (us) |\n|---|---|')
    for name, us in cost.items():
        print(f'| {name} | {us:.1f} |')
    print('\n| rate_hz | achieved (Hz) | jitter p50 (us) | jitter p99 (us) | longest period (ms) |')
    print('|---|---|---|---|---|')
    for rate, r in rows:
        print(f"| {rate:.0f} | {r['achieved_hz']:.1f} | {r['p50_us']:.0f} | {r['p99_us']:.0f} | "
              f"{r['max_period_ms']:.2f} |")
    print(f'\nA {ARRIVAL_POINTS}-point trajectory ({arrival["bytes"] / 1e6:.2f} MB) arriving at 100 Hz (wall clock, '
          'setpoint stamps = tick times): the longest gap between ticks from its publication until the node holds '
          f'it (diagnostics) plus 1 s: {arrival["after_ms"]:.1f} ms; in the {ARRIVAL_WINDOW_S:.0f} s before: '
          f'{arrival["before_ms"]:.1f} ms (the plan is decoded off the tick path).')


if __name__ == '__main__':
    main()
