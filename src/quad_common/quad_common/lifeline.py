"""A node's lifeline (no rclpy): it ends when the process that started it (`quadflight fly`) is gone, however
that died, SIGKILL included, so no node of a flight runs on under init."""

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
