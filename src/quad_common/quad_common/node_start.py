"""A node process's first code: its console script (each package's `start` module) records the stop signals
(SIGINT, SIGTERM) from here on, before the node's module imports rclpy, numpy and the rest (a second or more of
start-up on a busy machine), and quad_common.ros.node_main goes on recording into the same list. A Ctrl-C at any
moment of start-up therefore ends the node quietly with exit 0, never a KeyboardInterrupt traceback and exit -2
(`ros2 launch` sends SIGINT to every node at once). No rclpy here: this is what a console script imports first.
"""

import importlib
import signal

STARTUP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
received: list[int] = []   # the stop signals this process has received, in order


def record(signum, frame):
    received.append(signum)


def record_stop_signals():
    for sig in STARTUP_SIGNALS:
        signal.signal(sig, record)


def run(module: str) -> int:
    """The body of a node's console script: records stop signals, imports `module` and runs its main(); a stop
    that came during the import ends the process at once (exit 0: nothing was started)."""
    record_stop_signals()
    main = importlib.import_module(module).main
    if received:
        for sig in STARTUP_SIGNALS:   # Python's finalization must not turn a late Ctrl-C into -SIGINT
            signal.signal(sig, signal.SIG_IGN)
        return 0
    return main() or 0
