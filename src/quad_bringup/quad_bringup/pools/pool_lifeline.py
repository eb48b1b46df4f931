"""Imported by the local pool's forkserver (multiprocessing's preload) and called in each worker: the process
dies (SIGKILL) when its parent does, so a SIGKILLed sweep or tune leaves no forkserver, worker or resource tracker
behind (the tracker exits once no process holds its pipe). Linux prctl(PR_SET_PDEATHSIG); elsewhere
nothing is done."""

import ctypes
import os
import signal
import sys

POOL_PARENT_VARIABLE = 'QUADFLIGHT_POOL_PARENT_PID'   # the sweep's pid, set before the pool starts
_PR_SET_PDEATHSIG = 1


def die_with_parent(expected_parent: int | None = None):
    if not sys.platform.startswith('linux'):
        return
    try:
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    except (OSError, AttributeError):
        return
    if expected_parent is not None and os.getppid() != expected_parent:   # it died before prctl ran
        os._exit(1)


if os.environ.get(POOL_PARENT_VARIABLE) and os.getppid() == int(os.environ[POOL_PARENT_VARIABLE]):
    die_with_parent(int(os.environ[POOL_PARENT_VARIABLE]))   # the forkserver, started by the sweep itself
