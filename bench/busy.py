"""Another user's work on the shared machine, for the benches that measure beside it."""

import subprocess
import sys
import time
from contextlib import contextmanager


@contextmanager
def busy_loops(count: int, settle_s: float = 0.0):
    """`count` processes spinning a pure-Python loop while the body runs, killed after it. With settle_s, the body
    starts that long after them: the 1-minute load average (what the tables print) has risen to the load the body
    runs at, instead of climbing through it."""
    loops = [subprocess.Popen([sys.executable, '-c', 'while True: pass']) for _ in range(count)]
    try:
        if count:
            time.sleep(settle_s)
        yield
    finally:
        for loop in loops:
            loop.kill()
            loop.wait()
