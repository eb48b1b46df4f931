"""For tests: isolated ROS graphs (quad_common.domains, also what `quadflight fly` uses) and the probe harness the
node tests drive a node under test with."""

import threading
from contextlib import contextmanager

import rclpy
from rclpy.executors import SingleThreadedExecutor

from quad_common.domains import FASTDDS_PROFILE, isolated_domain  # noqa: F401  (the tests' import path)
from quad_common.ros.node_main import close_nodes

TIMEOUT_S = 60.0


class ProbeGraph:
    """A node under test (`self.node`, added by the test) and a `probe` node on one executor in context `ctx`.

    Everything waits on a condition (spin_until), never on elapsed time; TIMEOUT_S only bounds a hung wait.
    """

    def __init__(self, ctx):
        self.ctx = ctx
        self.executor = SingleThreadedExecutor(context=ctx)
        self.probe = rclpy.create_node('probe', context=ctx)
        self.executor.add_node(self.probe)
        self.node = None

    def spin_until(self, condition, what='condition'):
        deadline = self.probe.get_clock().now().nanoseconds + int(TIMEOUT_S * 1e9)
        while not condition():
            if self.probe.get_clock().now().nanoseconds > deadline:
                raise AssertionError(f'timed out waiting for {what}')
            self.executor.spin_once(timeout_sec=0.02)

    def close(self):
        close_nodes(self.executor, [n for n in (self.node, self.probe) if n is not None])


class Spinner:
    """Spins `executor` in a thread of its own until close(), which stops and joins that thread before it destroys
    `nodes` (quad_common.ros.node_main.close_nodes): a test's node is never destroyed under a wait or a callback."""

    def __init__(self, executor, nodes, name='spinner'):
        self.executor, self.nodes = executor, list(nodes)
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._run, name=name, daemon=True)
        self.thread.start()

    def _run(self):
        while not self._stop.is_set() and self.executor.context.ok():
            try:
                self.executor.spin_once(timeout_sec=0.05)
            except Exception:
                if self._stop.is_set() or not self.executor.context.ok():
                    return   # the context shut down under it
                raise

    def close(self):
        self._stop.set()
        close_nodes(self.executor, self.nodes, threads=[self.thread])


@contextmanager
def probe_graph(graph_class=ProbeGraph):
    """graph_class(ctx) in its own rclpy context on an isolated domain; closed and shut down on exit."""
    with isolated_domain() as (domain, _):
        ctx = rclpy.Context()
        rclpy.init(context=ctx, domain_id=domain)
        graph = graph_class(ctx)
        try:
            yield graph
        finally:
            graph.close()
            rclpy.shutdown(context=ctx)
