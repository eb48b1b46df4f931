"""The `main` every node shares: start-up refusal as exit status 2, spin until Ctrl-C/SIGTERM, clean shutdown;
bound to the life of the process that started it (quad_common.lifeline)."""

import re
import signal
import sys

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.signals import SignalHandlerOptions

from quad_common.lifeline import bind_to_parent

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)

def run_node(name, make_node, refused=(ValueError,), make_executor=None, spin=None, args=None, own_signals=False):
    """Builds the node (an exception in `refused`, e.g. a bad parameter, or a command line rcl cannot parse, e.g. a
    missing --params-file: one error line naming it, exit 2), adds it to `make_executor(node)` (default a
    SingleThreadedExecutor) and runs `spin(node, executor)` (default executor.spin()) until interrupted; then
    destroys the node and shuts the context down.

    own_signals: SIGINT/SIGTERM/SIGHUP do not shut rclpy down; they make `node.stop_requested()` true and `spin`
    returns when it has finished (e.g. the simulator's final diagnostics and drain)."""
    bind_to_parent()
    stop = []
    try:
        _init(args, own_signals, stop)
    except _rclpy.RCLError as exc:
        print(f'[ERROR] [{name}]: {name} refused to start: {rcl_reason(exc)}', file=sys.stderr)
        sys.exit(2)
    try:
        node = make_node()
    except refused as exc:
        rclpy.logging.get_logger(name).error(f'{name} refused to start: {exc}')
        rclpy.try_shutdown()
        sys.exit(2)
    if own_signals:
        node.stop_requested = lambda: bool(stop)
    executor = make_executor(node) if make_executor else SingleThreadedExecutor()
    executor.add_node(node)
    try:
        spin(node, executor) if spin else executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        if rclpy.ok():  # a signal's shutdown can surface as an RCLError inside the executor
            raise
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()


def _init(args, own_signals, stop):
    if own_signals:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
        for sig in STOP_SIGNALS:
            signal.signal(sig, lambda signum, frame: stop.append(signum))
        return
    # rclpy's own SIGINT/SIGTERM handler shuts the context down (the executor returns), then calls the handler it
    # found: this one, which only records the signal. Python's default raises KeyboardInterrupt wherever the
    # main thread is, e.g. inside destroy_node when `ros2 launch` forwards a second SIGINT during shutdown (a
    # traceback and exit -2 instead of a clean exit 0).
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda signum, frame: stop.append(signum))
    rclpy.init(args=args)


def rcl_reason(exc) -> str:
    """rcl's error without its C source locations (', at /project/src/parser.c:271')."""
    return re.sub(r', at [^,]*\.c:\d+', '', str(exc)).removeprefix('failed to initialize rcl: ')
