"""No node or entity is destroyed while another thread still uses it (a segfault, not an exception, in rcl):
the harness's close joins the spinning thread first (quad_common.ros.node_main.close_nodes, testing.Spinner), and
HotPathExecutor holds what it waits on in use, so an entity destroyed from another thread outlives the wait."""

import subprocess
import sys
import threading

import rclpy
from std_msgs.msg import Empty

from quad_common.ros.hot_path import HotPathExecutor
from quad_common.ros.testing import TIMEOUT_S, Spinner, isolated_domain

DESTROY_CYCLES = 200
CLOSE_BLOCKED_S = 0.5   # how long close() is watched for returning too early (a correct close cannot return)


def test_close_joins_the_spinning_thread_before_it_destroys_the_node():
    """close() while a callback of the spinning thread runs: it returns only after that callback, which still
    finds its node alive."""
    entered, release, seen = threading.Event(), threading.Event(), []
    with isolated_domain() as (domain, _):
        ctx = rclpy.Context()
        rclpy.init(context=ctx, domain_id=domain)
        try:
            node = rclpy.create_node('teardown_test', context=ctx)
            pub = node.create_publisher(Empty, 'poke', 10)

            def on_poke(_msg):
                entered.set()
                release.wait(TIMEOUT_S)
                seen.append(node.count_publishers('poke'))   # raises once the node is destroyed

            node.create_subscription(Empty, 'poke', on_poke, 10)
            executor = rclpy.executors.SingleThreadedExecutor(context=ctx)
            executor.add_node(node)
            spinner = Spinner(executor, [node])
            while not entered.wait(0.05):   # until the subscription is matched and the callback runs
                pub.publish(Empty())
            closer = threading.Thread(target=spinner.close)
            closer.start()
            closer.join(CLOSE_BLOCKED_S)
            still_closing = closer.is_alive()
            release.set()
            closer.join(TIMEOUT_S)
            assert not closer.is_alive() and not spinner.thread.is_alive()
        finally:
            rclpy.shutdown(context=ctx)
    assert still_closing, 'close() returned while a callback of the spinning thread was still running'
    assert seen == [1]


def _destroy_hot_subscriptions_while_waited_on(cycles):
    """A HotPathExecutor spins in a thread; the main thread creates a hot subscription, waits until the executor
    has asked for it (its next wait includes it) and destroys it, `cycles` times."""
    with isolated_domain() as (domain, _):
        ctx = rclpy.Context()
        rclpy.init(context=ctx, domain_id=domain)
        node = rclpy.create_node('hot_teardown_test', context=ctx)
        pub = node.create_publisher(Empty, 'hot', 10)
        hot, asked = [], threading.Condition()
        asked_for = []

        def entities():
            with asked:
                asked_for.append(tuple(hot))
                asked.notify_all()
                return list(hot), []

        executor = HotPathExecutor(entities, context=ctx)
        executor.add_node(node)
        spinner = Spinner(executor, [node])
        for _ in range(cycles):
            sub = node.create_subscription(Empty, 'hot', lambda _msg: None, 10)
            with asked:
                hot.append(sub)
                assert asked.wait_for(lambda: asked_for and sub in asked_for[-1], TIMEOUT_S)  # noqa: B023
                hot.remove(sub)
            node.destroy_subscription(sub)
            pub.publish(Empty())
        spinner.close()
        rclpy.shutdown(context=ctx)


def test_a_hot_subscription_destroyed_while_the_hot_path_waits_on_it():
    """In a process of its own: a use after free ends it with SIGSEGV, which the test reports."""
    done = subprocess.run([sys.executable, '-X', 'faulthandler', __file__, str(DESTROY_CYCLES)],
                          capture_output=True, text=True, timeout=10 * TIMEOUT_S)
    assert done.returncode == 0, done.stdout + done.stderr[-3000:]


if __name__ == '__main__':
    _destroy_hot_subscriptions_while_waited_on(int(sys.argv[1]))
