"""quad_common.lifeline.exit_now: the end of a process that has closed what it holds, without Python's
finalization, its output flushed (Python's and C's)."""

import os
import subprocess
import sys

import pytest

PROBE = """
import atexit, ctypes, sys
from quad_common.lifeline import exit_now
if sys.argv[1] == 'coverage':
    sys.modules['coverage'] = sys   # a coverage run has imported coverage
atexit.register(lambda: print('finalized', flush=True))
print('python line')                                        # buffered: stdout is a pipe
libc = ctypes.CDLL(None)
libc.fputs(b'c line\\n', ctypes.c_void_p.in_dll(libc, 'stdout'))   # C stdio, buffered too (a node's log line)
exit_now(3)
"""


@pytest.mark.parametrize('run', ['plain', 'coverage'])
def test_exit_now_skips_finalization_but_not_the_output(run):
    env = {k: v for k, v in os.environ.items() if k != 'PYTHONUNBUFFERED'}   # buffered, as a node's output is
    done = subprocess.run([sys.executable, '-c', PROBE, run], capture_output=True, text=True, timeout=60, env=env)
    assert done.returncode == 3, done.stderr
    assert 'python line' in done.stdout and 'c line' in done.stdout, done.stdout
    # finalization (atexit, module teardown) skipped, but under a coverage run, whose data is written then
    assert ('finalized' in done.stdout) == (run == 'coverage'), done.stdout
