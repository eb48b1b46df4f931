"""Node processes of a flight: each in its own process group, stopped so that nothing is orphaned.

Each node is also bound to fly's life (quad_common.lifeline.bind_to_parent, through PARENT_PID_VARIABLE): if fly
dies for any reason, SIGKILL included, every node gets SIGTERM (the recorder closes its bag) within a fraction
of a second.
"""

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from quad_bringup.pools.forked import ForkedProcess, can_fork
from quad_common.lifeline import PARENT_PID_VARIABLE


@dataclass
class NodeProcess:
    name: str
    module: str
    ros_args: list
    log_path: Path
    popen: subprocess.Popen | ForkedProcess | None = field(default=None, repr=False)
    argv: list = field(default_factory=list)   # before --ros-args
    remap_name: bool = True                    # -r __node:=NAME (not for a process of several nodes)
    fork: bool = False   # forked from this process where it has one thread (quad_bringup.pools.forked)

    def arguments(self) -> list[str]:
        """The module's command line after `python -m MODULE`."""
        name = ['-r', f'__node:={self.name}'] if self.remap_name else []
        return [*self.argv, '--ros-args', *name, *self.ros_args]

    def command(self) -> list[str]:
        return [sys.executable, '-m', self.module, *self.arguments()]

    def start(self, env):
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        with self.log_path.open('w') as log:
            # A new session: its own process group, so a signal to the group reaches everything it started,
            # and a Ctrl-C on fly's terminal reaches fly only (fly decides the order of stopping).
            env = dict(env, **{PARENT_PID_VARIABLE: str(os.getpid())})
            if self.fork and can_fork():
                null = os.open(os.devnull, os.O_RDONLY)
                try:
                    self.popen = ForkedProcess.start(lambda: _run_module(self.module, self.arguments(), env),
                                                     stdin=null, stdout=log.fileno(), stderr=log.fileno())
                finally:
                    os.close(null)
            else:
                self.popen = subprocess.Popen(self.command(), env=env, stdout=log, stderr=subprocess.STDOUT,
                                              stdin=subprocess.DEVNULL, start_new_session=True)

    @property
    def pid(self) -> int:
        return self.popen.pid

    def exit_code(self):
        return None if self.popen is None else self.popen.poll()

    def log_tail(self, lines=8) -> str:
        try:
            return '\n'.join(self.log_path.read_text(errors='replace').splitlines()[-lines:])
        except OSError:
            return ''

    def signal_group(self, sig):
        try:
            os.killpg(self.popen.pid, sig)
        except ProcessLookupError:
            pass


def _run_module(module: str, args: list[str], env: dict):
    """In a forked child: `python -m MODULE ARGS...` in environment env."""
    import runpy

    os.environ.clear()
    os.environ.update(env)
    sys.argv = [module, *args]
    runpy.run_module(module, run_name='__main__', alter_sys=True)
    return 0


HOST = 'node_host'   # the process that holds several nodes (quad_bringup.running.node_host)


def node_processes(specs, params_file: Path, log_dir: Path, hosted: bool) -> list[NodeProcess]:
    """The processes of a graph's nodes (graph.NodeSpec: name, namespace, module), in the specs' order: one node_host
    process for them all (its nodes served by one executor, their messages kept inside it), or one process per node
    as launch_ros starts them (-r __node:=NAME, -r __ns:=/NAMESPACE)."""
    args = ['--params-file', str(params_file)]
    if hosted:
        return [NodeProcess(HOST, 'quad_bringup.running.node_host', args, log_dir / f'{HOST}.log',
                            argv=[f'{s.name}@{s.namespace}' if s.namespace else s.name for s in specs],
                            remap_name=False, fork=True)]
    return [NodeProcess(s.name, s.module, [*(['-r', f'__ns:=/{s.namespace}'] if s.namespace else []), *args],
                        log_dir / (f'{s.namespace}_{s.name}.log' if s.namespace else f'{s.name}.log'))
            for s in specs]


def stop(processes, grace_s=10.0, log=print, idle=None):
    """SIGINT to every group, then SIGTERM, then SIGKILL to groups still alive after `grace_s` each.

    Returns {name: exit code}. Waits for each group leader, and kills the rest of its group. `idle(timeout_s)`,
    if given, is called while waiting (fly spins its monitor: a stopping simulator waits for its acknowledgements).
    """
    running = [p for p in processes if p.popen is not None]
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
        alive = [p for p in running if p.exit_code() is None]
        if not alive:
            break
        if sig != signal.SIGINT:
            log(f'{", ".join(p.name for p in alive)} still running: sending {signal.Signals(sig).name}')
        for p in alive:
            p.signal_group(sig)
        deadline = time.monotonic() + grace_s
        if idle is not None:
            while time.monotonic() < deadline and any(p.exit_code() is None for p in alive):
                idle(0.02)
            continue
        for p in alive:
            try:
                p.popen.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass
    for p in running:  # grandchildren, if a node started any
        p.signal_group(signal.SIGKILL)
    return {p.name: p.exit_code() for p in running}


def group_alive(pgid: int) -> bool:
    """True if any process of process group `pgid` still exists."""
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
