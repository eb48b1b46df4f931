"""A child forked from fly instead of a new interpreter: it inherits what fly has imported (numpy, rclpy, the
messages, the analysis modules: ~0.2-0.3 s of CPU per process on the 2-core machine), and nothing else of fly's.

Only a process with one thread may fork (`can_fork`): another thread may hold a lock the child would wait on forever
(DDS's, a pool's). The child: killed when fly dies (pool_lifeline.die_with_parent, from its first instruction: a
node's own lifeline may set a gentler signal later), its own session (a Ctrl-C on fly's terminal is fly's to handle,
as for start_new_session), the default signal handlers, its standard streams as given, every other inherited descriptor
closed (fly's run-directory and domain locks stay fly's), and it never returns into fly's code: `run()`'s return
value or SystemExit code is its exit status. ForkedProcess is the parent's handle, with the subprocess.Popen calls
fly uses (pid, poll, wait, send_signal, kill, returncode).
"""

import os
import select
import signal
import subprocess
import sys
import traceback

from quad_bringup.pools.pool_lifeline import die_with_parent


def can_fork() -> bool:
    """Whether this process has one thread (the operating system's count: numpy's OpenBLAS and DDS threads too)."""
    try:
        return len(os.listdir('/proc/self/task')) == 1
    except OSError:   # no /proc: never fork
        return False


class ForkedProcess:
    def __init__(self, pid: int):
        self.pid, self.returncode = pid, None

    @classmethod
    def start(cls, run, stdin: int, stdout: int, stderr: int, keep=()):
        """Forks a child that runs run() (module docstring); stdin/stdout/stderr: the descriptors its 0, 1 and 2
        become; keep: further descriptors it keeps open."""
        for stream in (sys.stdout, sys.stderr):   # else the child would write fly's buffered output again
            stream.flush()
        parent = os.getpid()
        pid = os.fork()
        if pid:
            return cls(pid)
        code = 1
        try:
            die_with_parent(parent)
            _become_child((stdin, stdout, stderr), keep)
            code = run()
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        except BaseException:
            traceback.print_exc()
        finally:
            for stream in (sys.stdout, sys.stderr):
                try:
                    stream.flush()
                except (OSError, ValueError):
                    pass
            os._exit(code if isinstance(code, int) else 0)

    def poll(self):
        if self.returncode is None:
            done, status = os.waitpid(self.pid, os.WNOHANG)
            if done:
                self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode

    def wait(self, timeout=None):
        """Its exit code; subprocess.TimeoutExpired after `timeout` seconds."""
        if self.returncode is None and timeout is not None:
            pidfd = os.pidfd_open(self.pid)
            try:
                if not select.select([pidfd], [], [], max(0.0, timeout))[0]:
                    raise subprocess.TimeoutExpired(f'process {self.pid}', timeout)
            finally:
                os.close(pidfd)
        if self.returncode is None:
            self.returncode = os.waitstatus_to_exitcode(os.waitpid(self.pid, 0)[1])
        return self.returncode

    def send_signal(self, sig):
        if self.poll() is None:
            os.kill(self.pid, sig)

    def kill(self):
        self.send_signal(signal.SIGKILL)


def _become_child(stdio, keep):
    os.setsid()
    signal.set_wakeup_fd(-1)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    for signum in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(signum, signal.SIG_DFL)
    for target, fd in enumerate(stdio):
        if fd != target:
            os.dup2(fd, target)
    kept = {0, 1, 2, *keep}
    for fd in [int(name) for name in os.listdir('/proc/self/fd')]:
        if fd not in kept:
            try:
                os.close(fd)
            except OSError:   # the listing's own descriptor, closed already
                pass
