"""quad_sim: physics steps/s of the core, and the real-time factor of the lockstep graph beside rotorpy."""

import os
import signal
import subprocess
import sys
import time

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from quad_common import conversions
from quad_common.compiled import COMPILED
from quad_common.domains import isolated_domain
from quad_common.sampled_trajectory import SampledTrajectory
from quad_common.types import AttitudeSetpoint
from quad_common.vehicle import load_vehicle
from quad_sim.simulator import Simulator

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MISSION_S = 20.0


def core_steps_per_s(seconds=4.0):
    sim = Simulator(load_vehicle(os.path.join(ROOT, 'config/vehicles/crazyflie.yaml')), initial_position=(0, 0, 1))
    sp = AttitudeSetpoint(quaternion=np.array([0.0, 0.02, 0.0, 1.0]) / np.linalg.norm([0.0, 0.02, 0.0, 1.0]))
    start = time.perf_counter()
    sim.warm_up()  # what sim_node does at start-up: load (first time: compile) the kernels
    warm_up_s = time.perf_counter() - start
    start = time.perf_counter()
    for _ in range(int(seconds * 100)):
        sim.set_setpoint(sp)
        sim.advance(0.01)
    wall = time.perf_counter() - start
    return seconds * 1000 / wall, seconds / wall, warm_up_s


def circle(duration_s=MISSION_S, radius_m=1.0):
    t = np.linspace(0, duration_s, int(duration_s * 100) + 1)
    w = 2 * np.pi / duration_s
    pos = np.stack([radius_m * np.cos(w * t) - radius_m, radius_m * np.sin(w * t), np.ones_like(t), 0 * t], 1)
    vel = np.stack([-radius_m * w * np.sin(w * t), radius_m * w * np.cos(w * t), 0 * t, 0 * t], 1)
    acc = np.stack([-radius_m * w**2 * np.cos(w * t), -radius_m * w**2 * np.sin(w * t), 0 * t, 0 * t], 1)
    return SampledTrajectory(t, pos, vel, acc)


def graph_rtf():
    """sim_node + position_controller as processes; the bench publishes the trajectory (latched)."""
    with isolated_domain() as (domain, env):
        env = dict(env, PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
        ctx = rclpy.Context()
        rclpy.init(context=ctx, domain_id=domain)
        node = rclpy.create_node('bench', context=ctx)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        node.create_publisher(type(conversions.sampled_to_msg(circle(), conversions.s_to_stamp(0))), 'trajectory',
                              latched).publish(conversions.sampled_to_msg(circle(), conversions.s_to_stamp(1.0)))
        first, last = [None, None], [0.0, None]  # (sim time, wall time) of the first and newest diagnostics

        def on_diagnostics(msg):  # sim_node's, once per sim second: watching costs the 2 cores next to nothing
            t = conversions.stamp_to_s(msg.header.stamp)
            if t > 0 and first[0] is None:
                first[:] = t, time.perf_counter()
            if first[0] is not None and t > last[0]:
                last[:] = t, time.perf_counter()
        node.create_subscription(DiagnosticArray, 'diagnostics', on_diagnostics, QoSProfile(depth=10))
        executor = rclpy.executors.SingleThreadedExecutor(context=ctx)
        executor.add_node(node)
        deadline = time.monotonic() + 200
        procs = []
        for m, a in (('quad_sim.sim_node', ['-p', 'initial_position:=[0.0, 0.0, 1.0]']),
                     ('quad_control.position_controller_node', ['-p', 'lockstep:=true', '-p', 'use_sim_time:=true'])):
            procs.append(subprocess.Popen([sys.executable, '-m', m, '--ros-args', *a], env=env,
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
            # the sim holds t = 0 until a controller is up: start that once the bench sees the sim's diagnostics
            # publisher, else a fast graph can fly the whole mission before the bench is matched
            while not node.get_publishers_info_by_topic('diagnostics') and time.monotonic() < deadline:
                executor.spin_once(timeout_sec=0.1)
        while last[0] < MISSION_S + 1.0 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.5)
        wall = last[1] - first[1]
        for p in procs:
            p.send_signal(signal.SIGINT)
            p.wait(timeout=30)
        executor.shutdown()
        rclpy.shutdown(context=ctx)
        return (last[0] - first[0]) / wall


ROTORPY = '''
import time, numpy as np
from rotorpy.vehicles.multirotor import Multirotor
from rotorpy.vehicles.crazyflie_params import quad_params
from rotorpy.controllers.quadrotor_control import SE3Control
from rotorpy.trajectories.circular_traj import ThreeDCircularTraj
from rotorpy.environments import Environment
env = Environment(vehicle=Multirotor(quad_params), controller=SE3Control(quad_params),
                  trajectory=ThreeDCircularTraj(radius=np.array([1.0, 1.0, 0.0]), freq=np.array([0.05, 0.05, 0.0])),
                  sim_rate=100)
start = time.perf_counter()
env.run(t_final=20.0, use_mocap=False, terminate=False, plot=False, animate_bool=False, verbose=False)
print(20.0 / (time.perf_counter() - start))
'''


def rotorpy_rtf():
    try:
        from quad_bringup.peers.peer_venv import run_peer
        return f'{float(run_peer(ROTORPY, timeout_s=200).split()[-1]):.1f}x'
    except Exception as exc:  # the peer is optional: report why it is missing
        return f'n/a ({type(exc).__name__})'


def main():
    steps, rtf_core, warm_up_s = core_steps_per_s()
    rtf_graph = graph_rtf()
    peer = rotorpy_rtf()
    print('### quad_sim: physics core and lockstep graph\n')
    print('Core: one Crazyflie, 1 kHz RK4 + onboard eq. 6 + mixer, 4 s. Graph: sim_node + position_controller '
          '(separate processes, lockstep, 100 Hz control) flying a 20 s circle; rotorpy 3.0.0 flies the same circle '
          'with its own SE3 controller at 100 Hz in its own venv.\n')
    print('| measurement | ours | rotorpy | goal |\n|---|---|---|---|')
    how = 'numba' if COMPILED else 'interpreted: numba missing'
    print(f'| core physics steps/s (1 kHz, {how}) | {steps:,.0f} ({rtf_core:.1f}x real time) | | 200x |')
    print(f'| core start-up: kernel load (compile if not cached) | {warm_up_s:.2f} s | | |')
    print(f'| lockstep graph real-time factor (100 Hz control) | {rtf_graph:.1f}x | {peer} | 10x |')


if __name__ == '__main__':
    main()
