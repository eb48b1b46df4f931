"""node_host: several nodes in one process (a fleet's simulator, planners and controllers; fly's one vehicle).

    python -m quad_bringup.running.node_host [sim_node] position_controller@cf1 trajectory_node@cf1 ... \
        --ros-args --params-file F
    python -m quad_bringup.running.node_host recorder trajectory_node sim_node position_controller --ros-args \
        --params-file F

Each NAME@NAMESPACE is the node of that executable (quad_bringup.running.graph.MODULES) built with that namespace, a
plain NAME the node without one (fly's graph, named as sim.launch.py names it); the params files' sections are
fully qualified node names (/cf1/position_controller, or position_controller), as rcl applies one file to every
node of a process. Why one process: a fleet of N vehicles as 2 N processes costs N interpreters, N DDS
participants and N x 2 context switches per lockstep step; in one process the controllers' ticks are served in
one pass of one HotPathExecutor (every controller's hot entities), the planners in its slow pass. A node that
refuses its parameters stops the whole process (exit 2, naming it), as a single node does.

On simulated time the nodes share one /clock subscription (`share_clock`): each rclpy node otherwise subscribes
/clock itself, N takes of every /clock message per step; here the first node's time source drives every node's
clock (rclpy's TimeSource.attach_clock, the API a node's own time source uses), the others' subscriptions are
removed.

With `sim_node` (no namespace: the fleet's one simulator) the simulator's lockstep loop is the process's loop: each
of its waits serves the controllers' ticks, and odometry and setpoints go from writer to reader inside the process
(Fast DDS delivers within a participant without a transport or a wake-up of another process): per step 2 N fewer
cross-process deliveries and no context switch on the lockstep's path (4 vehicles: 4.9x -> 5.7x real time, median
of 5 interleaved runs on the loaded 2-core machine). Stop signals then reach the simulator (its final diagnostics
and the recorder's drain), as a lone sim_node's do.

`recorder` (no namespace, beside sim_node only: fly's graph, a fleet's) records in the same process: every message
reaches it without leaving the process; beside a lockstep simulator it takes what is queued once a step
(recorder_node.take_step), its subscriptions out of the executor's wait set; at the
simulator's stop, once its final counts are published, it takes what is queued and closes the bag (close_recorder),
before the simulator waits for followers in other processes.
"""

import importlib
import sys

from quad_common.lifeline import exit_now
from quad_common.ros.hot_path import HotPathExecutor
from quad_common.ros.node_main import run_node

# executable -> (module, node class) of the nodes a host can hold
HOSTABLE = {
    'position_controller': ('quad_control.position_controller_node', 'PositionControllerNode'),
    'trajectory_node': ('quad_trajectory.trajectory_node', 'TrajectoryNode'),
    'sim_node': ('quad_sim.sim_node', 'SimNode'),   # no namespace: the fleet's one simulator
    'recorder': ('quad_bringup.recording.recorder_node', 'RecorderNode'),   # no namespace, beside sim_node only
}
SIMULATOR = 'sim_node'
RECORDER = 'recorder'
GLOBAL = (SIMULATOR, RECORDER)   # the nodes a host holds without a namespace only


def parse_nodes(argv: list[str]) -> tuple[list[tuple[str, str]], list[str]]:
    """([(executable, namespace)], the --ros-args part) of the command line; ValueError naming a bad entry."""
    ros_args = argv[argv.index('--ros-args'):] if '--ros-args' in argv else []
    entries = argv[:len(argv) - len(ros_args)]
    nodes = []
    for entry in entries:
        name, at, namespace = entry.partition('@')
        namespace = namespace.strip('/')
        if name not in HOSTABLE or (at and not namespace) or (name in GLOBAL and namespace):
            raise ValueError(f'node {entry!r} refused: NAME or NAME@NAMESPACE with NAME one of '
                             f'{", ".join(n for n in HOSTABLE if n not in GLOBAL)}, or {" or ".join(GLOBAL)} '
                             '(no namespace)')
        nodes.append((name, namespace))
    if not nodes:
        raise ValueError('no nodes given: NAME or NAME@NAMESPACE ...')
    if (RECORDER, '') in nodes and (SIMULATOR, '') not in nodes:
        raise ValueError(f'node {RECORDER!r} refused without {SIMULATOR}: a hosted recorder drains and closes its bag '
                         "after the simulator's loop, on the host's own stop signals")
    if len(set(nodes)) != len(nodes):
        raise ValueError(f'node {next(f"{n}@{ns}" for n, ns in nodes if nodes.count((n, ns)) > 1)!r} given twice')
    return nodes, ros_args


def hot_entities(nodes, clock_subscription=None):
    """Every node's per-tick entities (a node without hot_entities is served in the slow pass), the shared /clock
    subscription first."""
    subscriptions, timers, guards = [clock_subscription] if clock_subscription is not None else [], [], []
    for node in nodes:
        if hasattr(node, 'hot_entities'):
            subs, node_timers, *node_guards = node.hot_entities()
            subscriptions += [sub for sub in subs if sub is not clock_subscription]
            timers += node_timers
            guards += node_guards[0] if node_guards else []
    return subscriptions, timers, guards


def share_clock(nodes):
    """The first node's time source drives every other node's ROS clock; their own /clock subscriptions are
    removed (all nodes of a host are on simulated time or none; a mix is refused). Returns the one /clock
    subscription left (None on wall-clock time): a hot entity, as every tick waits for it."""
    sim_time = [bool(node.get_parameter('use_sim_time').value) for node in nodes]
    if any(sim_time) and not all(sim_time):
        raise ValueError('use_sim_time differs between the hosted nodes: '
                         + ', '.join(f'{n.get_fully_qualified_name()}={t}' for n, t in zip(nodes, sim_time)))
    if not all(sim_time):
        return None
    source = nodes[0]._time_source   # rclpy 7.1 (quad_common.ros.hot_path.CHECKED_RCLPY_VERSION)
    for node in nodes[1:]:
        node._time_source.detach_node()
        source.attach_clock(node.get_clock())
    return source._clock_sub


def taken_per_step(entries, nodes) -> list:
    """The nodes served once a lockstep step (recorder_node.take_step) instead of by the executor's wait set: a
    recorder beside a simulator in lockstep mode. In realtime mode there are no steps: the recorder is served as the
    others are."""
    if (RECORDER, '') not in entries or nodes[entries.index((SIMULATOR, ''))].params['mode'] != 'lockstep':
        return []
    return [nodes[entries.index((RECORDER, ''))]]


def close_recorder(recorder):
    """A hosted recorder's drain: what the simulator published, its final counts included, is queued already (a
    publisher in this process delivers as it publishes): take it and close the bag. At the simulator's stop, before it
    waits for its followers: fly's monitor, in another process, may be gone without the graph knowing it yet (fly
    killed: its DDS participant stays until its lease runs out), and this process is killed 5 s after fly's death
    (quad_common.lifeline)."""
    from quad_bringup.recording.recorder_node import take_queued

    if not recorder.closed:
        take_queued(recorder)
        recorder.close_bag()


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        entries, ros_args = parse_nodes(argv)
    except ValueError as exc:
        print(f'node_host: {exc}', file=sys.stderr)
        sys.exit(2)

    clock = [None]
    simulated = any(name == SIMULATOR for name, _ in entries)
    stepped = []   # a recorder beside a lockstep simulator: served once a step, not in the wait set

    def make_nodes():
        nodes = []
        for name, namespace in entries:
            module, cls = HOSTABLE[name]
            try:
                nodes.append(getattr(importlib.import_module(module), cls)(
                    **({'namespace': namespace} if namespace else {})))
            except ValueError as exc:
                for node in nodes:
                    node.destroy_node()
                raise ValueError(f'{f"/{namespace}" if namespace else ""}/{name}: {exc}') from None
        # the recorder stamps with the system clock (receive times, as `ros2 bag record`): not on the shared /clock
        clock[:] = [share_clock([node for (name, _), node in zip(entries, nodes) if name != RECORDER])]
        stepped[:] = taken_per_step(entries, nodes)
        return nodes

    def make_executor(nodes):
        served = [node for node in nodes if node not in stepped]
        return HotPathExecutor(lambda: hot_entities(served, clock[0]))

    def spin(nodes, executor):
        if not simulated:
            return executor.spin()
        from quad_sim import sim_node

        simulator = nodes[entries.index((SIMULATOR, ''))]
        recorder = nodes[entries.index((RECORDER, ''))] if (RECORDER, '') in entries else None
        if recorder is not None:
            if recorder in stepped:
                from quad_bringup.recording.recorder_node import take_step

                simulator.each_step.append(lambda: take_step(recorder))
            simulator.at_final_counts.append(lambda executor: close_recorder(recorder))
        sim_node.spin(simulator, executor)
        if recorder is not None:   # a stop that did not reach the lockstep's drain (realtime mode)
            close_recorder(recorder)

    run_node('node_host', make_nodes, refused=(ValueError, OSError),
             make_executor=make_executor,
             spin=spin, args=['node_host', *ros_args], own_signals=simulated)


if __name__ == '__main__':
    main()
    # stopped: the nodes destroyed (a hosted recorder's bag closed), rclpy shut down; fly waits for this exit
    exit_now(0)
