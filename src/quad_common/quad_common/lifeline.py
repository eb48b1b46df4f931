"""A node's lifeline (no rclpy): it ends when the process that started it (`quadflight fly`) is gone, however
that died, SIGKILL included, so no node of a flight runs on under init; and its end without Python's finalization
once it has closed what it holds (exit_now)."""

import ctypes
import os
import signal
import sys
import threading
import time

PARENT_PID_VARIABLE = 'QUADFLIGHT_PARENT_PID'  # set by quad_bringup.running.processes for the nodes it starts
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


def exit_now(code: int):
    """Ends the process without Python's finalization, for a process whose files, nodes and children are closed
    already: tearing down its modules (numba's and llvmlite's, matplotlib's, rclpy's) costs 0.15-0.2 s of CPU in a
    process that holds the simulator and only delays whoever waits for its exit. Python's and C's buffered output
    (stdout, stderr; a node's log lines) is flushed first. Under a coverage run (its data is written at
    finalization) the process exits the ordinary way."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (BrokenPipeError, ValueError):   # the reader is gone; or the stream is closed
            pass
    if 'coverage' in sys.modules:
        sys.exit(code)
    try:
        ctypes.CDLL(None).fflush(None)   # C stdio: rcutils' log lines
    except (OSError, AttributeError):
        pass
    os._exit(code)
