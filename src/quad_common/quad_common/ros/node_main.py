"""The `main` every node shares: start-up refusal as exit status 2, spin until Ctrl-C/SIGTERM, clean shutdown;
bound to the life of the process that started it (quad_common.lifeline)."""

import inspect
import re
import signal
import sys
from types import SimpleNamespace

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.signals import SignalHandlerOptions

from quad_common import node_start
from quad_common.lifeline import bind_to_parent
from quad_common.realtime import freeze_startup_heap

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class _CallerFile:
    """What rclpy's logger (rclpy.impl.rcutils_logger, rclpy hot_path.CHECKED_RCLPY_VERSION) uses of `inspect`: the
    current frame, and a frame's file through getframeinfo(frame).filename, which is the frame's code's file for
    source files; getframeinfo also reads the source and searches every loaded module for it, ~3.5 ms per log call
    in a node process (~800 modules) and ~35 ms for the first."""

    currentframe = staticmethod(inspect.currentframe)

    @staticmethod
    def getframeinfo(frame):
        return SimpleNamespace(filename=frame.f_code.co_filename)


def lean_log_caller():
    """rclpy's logger finds the caller of a log call (for its once/throttle filters) from the frame's file alone."""
    from rclpy.impl import rcutils_logger

    rcutils_logger.inspect = _CallerFile


def run_node(name, make_node, refused=(ValueError,), make_executor=None, spin=None, args=None, own_signals=False):
    """Builds the node (an exception in `refused`, e.g. a bad parameter, or a command line rcl cannot parse, e.g. a
    missing --params-file: one error line naming it, exit 2), adds it to `make_executor(node)` (default a
    SingleThreadedExecutor) and runs `spin(node, executor)` (default executor.spin()) until interrupted; then
    destroys the node and shuts the context down. make_node may return a list of nodes (one process hosting
    several: quad_bringup.running.node_host); make_executor and spin then get the list.

    own_signals: SIGINT/SIGTERM/SIGHUP do not shut rclpy down; they make `node.stop_requested()` true and `spin`
    returns when it has finished (e.g. the simulator's final diagnostics and drain)."""
    stop = node_start.received   # a stop recorded since the console script's first line counts
    node_start.record_stop_signals()
    bind_to_parent()
    lean_log_caller()
    if stop:   # Ctrl-C before anything was built
        ignore_stop_signals()
        return
    try:
        _init(args, own_signals, stop)
    except _rclpy.RCLError as exc:
        print(f'[ERROR] [{name}]: {name} refused to start: {rcl_reason(exc)}', file=sys.stderr)
        sys.exit(2)
    node = executor = None
    try:
        if _stopping(stop):   # Ctrl-C while rclpy was starting
            return
        node = make_node()
        if own_signals:
            for each in node if isinstance(node, list) else [node]:
                each.stop_requested = lambda: bool(stop)
        if _stopping(stop):
            return
        executor = make_executor(node) if make_executor else SingleThreadedExecutor()
        for each in node if isinstance(node, list) else [node]:
            executor.add_node(each)
        freeze_startup_heap()   # no full collection of the start-up heap while flying
        spin(node, executor) if spin else executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except refused as exc:
        if _stopping(stop):
            _drop_rclpy_destructor_noise()
            return
        if node is not None:
            raise
        rclpy.logging.get_logger(name).error(f'{name} refused to start: {exc}')
        sys.exit(2)
    except Exception:
        # Ctrl-C while the node or its executor is still being built shuts the context down under them (rcl
        # errors, invalid handles): a stop, not a crash. An error with nobody stopping us is a crash.
        if not _stopping(stop):
            raise
        _drop_rclpy_destructor_noise()
    finally:
        _finish(node, executor)


def _stopping(stop) -> bool:
    return bool(stop) or not rclpy.ok()


def _drop_rclpy_destructor_noise():
    """rclpy objects left half built when Ctrl-C shut the context down under them (an executor, a guard
    condition) raise AttributeError from their __del__, which Python prints as a traceback at exit. They are
    being dropped on purpose: say nothing about them; anything else unraisable is still printed."""
    default_hook = sys.unraisablehook

    def hook(unraisable):
        if not getattr(unraisable.object, '__module__', '').startswith('rclpy.'):
            default_hook(unraisable)

    sys.unraisablehook = hook


def _finish(node, executor):
    try:
        close_nodes(executor, node if isinstance(node, list) else [] if node is None else [node])
    finally:
        rclpy.try_shutdown()
        ignore_stop_signals()


JOIN_TIMEOUT_S = 30.0   # a hang guard only: a spinning thread is woken at once and returns after its callback


def close_nodes(executor, nodes, threads=(), join_timeout_s=JOIN_TIMEOUT_S):
    """Tears nodes down in the one order that cannot destroy an entity while something still uses it: every
    thread that spins `executor` or otherwise uses the nodes (already told to stop) is woken and joined, then the
    nodes leave the executor, the executor shuts down, and only then are the nodes destroyed. rcl frees a
    subscription, timer or guard condition at once on destroy; a wait set or callback of another thread still
    holding it reads freed memory (a segfault). A thread still alive after join_timeout_s: RuntimeError, and the
    nodes are left as they are (a leak, never a crash)."""
    if executor is not None:
        executor.wake()
    for thread in threads:
        thread.join(timeout=join_timeout_s)
        if thread.is_alive():
            raise RuntimeError(f'thread {thread.name!r} still runs {join_timeout_s} s after it was told to stop: '
                               'its nodes are not destroyed under it')
    if executor is not None:
        for node in nodes:
            executor.remove_node(node)
        executor.shutdown()
    for node in nodes:
        node.destroy_node()


def ignore_stop_signals():
    """Once shut down, further stop signals are moot: Python's finalization puts a handled SIGINT back to its
    default action, so a second Ctrl-C arriving while the interpreter exits (`ros2 launch` forwards one) would
    end the process with -SIGINT instead of 0. An ignored signal stays ignored."""
    for sig in STOP_SIGNALS:
        signal.signal(sig, signal.SIG_IGN)

def _init(args, own_signals, stop):
    if own_signals:
        for sig in STOP_SIGNALS:
            signal.signal(sig, lambda signum, frame: stop.append(signum))
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
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
