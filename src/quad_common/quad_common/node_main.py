"""The `main` every node shares: start-up refusal as exit status 2, spin until Ctrl-C/SIGTERM, clean shutdown;
and the lifeline that ends a node whose parent (`quadflight fly`) is gone, however it died."""

import ctypes
import os
import signal
import sys
import threading
import time

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions

PARENT_PID_VARIABLE = 'QUADFLIGHT_PARENT_PID'  # set by quad_bringup.processes for the nodes it starts
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
_PR_SET_PDEATHSIG = 1
LIFELINE_POLL_S = 0.25


def bind_to_parent(sig=signal.SIGTERM):
    """If started by fly (PARENT_PID_VARIABLE): receive `sig` when the parent dies, SIGKILL included.

    Linux: prctl(PR_SET_PDEATHSIG) (the kernel sends it when the parent exits); everywhere, as a fallback, a daemon
    thread that sends `sig` to this process once its parent pid changes (re-parented to init or a subreaper).
    A parent that died before this ran is caught by the first check.
    """
    expected = os.environ.get(PARENT_PID_VARIABLE)
    if not expected:
        return
    expected = int(expected)
    if sys.platform.startswith('linux'):
        try:
            ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0)
        except (OSError, AttributeError):
            pass

    def watch():
        while os.getppid() == expected:
            time.sleep(LIFELINE_POLL_S)
        os.kill(os.getpid(), sig)
        time.sleep(5.0)            # a clean shutdown takes well under this
        os.kill(os.getpid(), signal.SIGKILL)

    threading.Thread(target=watch, name='lifeline', daemon=True).start()


def run_node(name, make_node, refused=(ValueError,), make_executor=None, spin=None, args=None, own_signals=False):
    """Builds the node (an exception in `refused`, e.g. a bad parameter: one error line naming it, exit 2), adds
    it to `make_executor(node)` (default a SingleThreadedExecutor) and runs `spin(node, executor)` (default
    executor.spin()) until interrupted; then destroys the node and shuts the context down.

    own_signals: SIGINT/SIGTERM/SIGHUP do not shut rclpy down; they make `node.stop_requested()` true and `spin`
    returns when it has finished (e.g. the simulator's final diagnostics and drain)."""
    bind_to_parent()
    stop = []
    if own_signals:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
        for sig in STOP_SIGNALS:
            signal.signal(sig, lambda signum, frame: stop.append(signum))
    else:
        rclpy.init(args=args)
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
