"""Fleets through the ROS graph (`quadflight fleet FLEET.yaml --graph`): lockstep real-time factor at 1, 4, 16 and 64
vehicles on this machine, beside Crazyswarm2's published figures and the same fleets offline (fleet_loop)."""

import os
import statistics
import sys
import tempfile
import time

from bench_fleet import SPACING_M, grid_fleet
from busy import busy_loops

from quad_bringup.offline.fleet_loop import fly_fleet
from quad_bringup.running.fleet_graph import fly_graph
from quad_trajectory.fleet import plan_fleet

NOTE = ('\n' +
        'The lockstep is serial: each step sim_node publishes every odometry, the controllers answer, '
        'sim_node takes every setpoint and advances, so the rate falls as 1/N. With the simulator in the '
        "vehicles' process (node_host, the default) odometry and setpoints go from writer to reader inside "
        'that process, the recorder\'s copy too (it is a node of that process, served once a step); what is left '
        'per message is Python (rclpy take, the controller, cdr packing, ~0.1 ms per vehicle and step). With the '
        'recorder in a process of its own (until 2026-12-07) each write to it woke that process, ~30 us of the '
        'writer\'s wall time on 2 cores, and on a shared machine its process took the core the lockstep needed: '
        'against that tree (14b437d), 16 vehicles beside a busy loop 2.94x against 1.76x (medians of 5 interleaved '
        'pairs, load 0.6-2.1 by the 1-minute average), beside two 2.58x against 1.54x (3 pairs), quiet 2.54x '
        'against 2.77x (3 pairs: within the noise). Hosted but served by the host\'s wait set like any node (its '
        '~65 subscriptions in every pass of the lockstep\'s loop, ~150 us each pass), beside a busy loop: 2.07x '
        'against 1.21x. A subscription whose last take found nothing (the plans and diagnostics: half of them) '
        'taken again 8 steps later, not every step, against every one every step (73c0c11): quiet 3.85x, 3.90x and '
        '3.44x against 3.58x, 3.43x and 2.49x (3 interleaved pairs; the vehicles\' process 2.8-3.2 s of CPU a '
        'flight against 3.0-4.4 s), beside a busy loop 2.65x against 2.09x (medians of 4 pairs). Beside a busy '
        'loop the same flight costs the vehicles\' process 3.2-7.4 s of CPU against 2.8-3.2 s quiet: the two '
        'cores share more than time. Before this (sim_node in a process of its own; the '
        "executor's pass over every entity every 0.1 s however long it took) the quiet machine gave medians "
        'of 4.6x at 4 vehicles (13 runs, 1.9-7.1x), 1.3x at 16 and 0.10x at 64. Hosting the simulator: 4 '
        'vehicles 3.7-4.9x -> 5.7-5.9x median in interleaved runs on the loaded machine; the slow pass '
        'bounded to a tenth of the loop: 16 vehicles 1.6x -> 2.9-4.0x, 32 vehicles 0.47x -> 1.08x (same '
        "machine, loaded). Building /tf, imu and rotor_speeds and the controllers' control/reference only "
        'while subscribed (a fleet publishes them to nobody) took 4 vehicles from 3.4x to 5-7x before that. '
        'sim_node logs its longest wait for setpoints and for the recorder (`lockstep: longest wait for '
        '...`; the recorder\'s in the table): a slow run shows where it lost its time.\n\n'
        'The recorder in a process of its own (one per node, --process-per-node) holds the lockstep only while it '
        'is more than 40 steps behind: at 16 vehicles on a machine '
        'that is not starved (load 1.3-2.4) its longest wait was 0.1-0.9 ms in every run; stopped (SIGSTOP) for 1 s '
        'it held sim_node 0.83 s, nothing lost. The waits of seconds came from a DDS sample it lost while '
        'descheduled, asked again only at the writer\'s next heartbeat (3 s; 50 ms since, the Fast DDS profile), '
        'and its flush\'s fsync ran on its one thread (beside one 800 MB write: 120-186 ms; now in a thread of its '
        'own). It acknowledges every 10 steps (it did every 10 odometry messages: 1.6 a step at 16 vehicles) and '
        'takes a ready subscription\'s backlog in one wake-up; after a wake-up that took messages it pauses '
        'take_pause_s (5 ms), so a step\'s burst is one wake-up, not one per message: at 16 vehicles its CPU fell '
        'from 3.4-4.2 s to 1.8-2.2 s a flight, and with a busy loop beside them the stepping rose from 1.94x to '
        '2.38x median (6 interleaved pairs, load 2.9-3.6; sim_node\'s writes, each waking the recorder, took '
        '26-30 us against 32-47); on a quiet machine the rate did not change beyond the noise. '
        'Where the stepping goes at 16 vehicles, the recorder hosted and taken once a step (py-spy --nonblocking, the '
        'vehicles\' process\'s samples on CPU while stepping): the controllers\' ticks ~24 %, their and the '
        'simulator\'s DDS writes ~14 %, the executor\'s hot passes ~8 %, the stock executor\'s pass once a second '
        'and the probe of the entities that are not hot ~10 %, the physics ~6 %: Python per vehicle and step, a '
        'few percent each. Before the hosting the DDS writes to the recorder\'s process were ~25 %.')

SIZES = (1, 4, 16, 64)
PER_NODE_SIZES = (1, 4)      # one process per node (as launch_ros starts them) beside one process for the nodes
BUSY_SIZES = (16,)           # again beside a busy loop (the goal's load ~4: the graph's own ~2-3, and one more core's)
REPEATS = {1: 5, 4: 7, 16: 5, 64: 1}   # runs per row (the spread from run to run is wide on a shared machine)
CRAZYSWARM2 = {1: '0.70x', 4: '0.15x (5 drones)', 16: '0.05x', 64: ''}   # Crazyswarm2's own measurement (its machine)
GOAL = {4: 5.0, 16: 3.0}


def main():
    rows, verdicts = [], []
    for n in SIZES:
        plan = plan_fleet(grid_fleet(n))
        offline = fly_fleet(plan.fleet, fleet_plan=plan)
        layouts = [(True, 0)] + [(False, 0)] * (n in PER_NODE_SIZES) + [(True, 1)] * (n in BUSY_SIZES)
        for hosted, busy in layouts:
            rtf, command, done, rmse, load, follower_ms = [], [], [], [], [], []
            for _ in range(REPEATS[n]):
                with tempfile.TemporaryDirectory() as out, busy_loops(busy):
                    start = time.perf_counter()
                    run, timing = fly_graph(plan, out, hosted=hosted, log=lambda *_: None)
                    command.append(time.perf_counter() - start)
                load.append(os.getloadavg()[0])
                follower_ms.append(timing.follower_wait_ms)
                rtf.append(run.sim_s / timing.flight_s)
                done.append(sum(m['completed'] and not m['collided'] for m in run.metrics.values()))
                rmse.append(max(m['rmse_m'] for m in run.metrics.values()))
                layout = ('one process' if hosted else 'one per node') + ', a busy loop beside' * busy
                print(f'{n} vehicles ({layout}): {rtf[-1]:.2f}x stepping, command {command[-1]:.1f} s',
                      file=sys.stderr)
            med = statistics.median(rtf)
            rows.append(f'| {n} | {layout} | {len(rtf)} | {run.sim_s:.2f} | '
                        f'**{med:.2f}x** | {min(rtf):.2f}-{max(rtf):.2f}x | {statistics.median(command):.1f} | '
                        f'{run.sim_s / statistics.median(command):.2f}x | {min(done)}/{n} | {max(rmse) * 100:.2f} | '
                        f'{offline.real_time_factor:.1f}x | {min(load):.1f}-{max(load):.1f} | '
                        f'{max(follower_ms):.1f} | {CRAZYSWARM2[n]} |')
            if hosted and n in GOAL:
                verdicts.append(f'- {n} vehicles{", a busy loop beside" * busy}: median {med:.2f}x over {len(rtf)} '
                                f'runs against >= {GOAL[n]:g}x: '
                                f'{"met" if med >= GOAL[n] else "NOT met"} ({sum(r >= GOAL[n] for r in rtf)} of '
                                f'{len(rtf)} runs at or above it)')
    print('## Fleets through the ROS graph (bench_fleet_graph)\n')
    print(f'`quadflight fleet --graph`: N Crazyflies in a square grid {SPACING_M} m apart on '
          '`fleets/formation4.yaml`\'s path; one sim_node steps them all in lockstep (1 kHz physics, 100 Hz setpoints, '
          'one /clock, each vehicle\'s topics under its namespace), each vehicle\'s trajectory_node and '
          'position_controller (pd) under its namespace, the recorder (every vehicle\'s odom, setpoints, plan and '
          'diagnostics) as the lockstep follower: nothing lost. sim_node, the vehicles\' nodes and the recorder run in '
          'one process (quad_bringup.running.node_host, the default) or, for 1 and 4 vehicles, one process per '
          'node as launch_ros starts them; 16 vehicles again beside a busy loop (a pure-Python loop in a process of '
          'its own: the goal\'s load). Stepping = sim_node\'s wall time from its first step to its '
          'last (the real-time factor: simulated / stepping); the command = what the user waits for (processes '
          'started, planned, flown, stopped, the bag read and scored). Runs per row: the median and the range. '
          'Beside them the same fleet offline (fleet_loop, no ROS) and Crazyswarm2\'s simulation through ROS with '
          '/clock (its own measurement, its machine). Goal: >= 5x at 4 vehicles and >= 3x at 16 (at load ~4); '
          'the longest wait for the recorder: a step\'s worth (~10 ms at 16 vehicles) while the machine is not '
          'starved.\n')
    print('| vehicles | nodes | runs | simulated (s) | real-time factor (median) | range | command wall (s) | '
          'command real-time factor | completed (worst run) | worst rmse (cm) | offline (fleet_loop) | '
          'load (1 min, after each run) | longest wait for the recorder (ms, worst run) | Crazyswarm2 |')
    print('|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|')
    print('\n'.join(rows))
    print('\n' + '\n'.join(verdicts))
    print(NOTE)


if __name__ == '__main__':
    main()
