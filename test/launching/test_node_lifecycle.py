"""Every node's console script as launch_ros starts it (`--ros-args -r __node:=NAME ...`): Ctrl-C in a terminal
running `ros2 launch` (SIGINT to every process, then launch forwards a second one during shutdown) ends it with
exit 0 and no traceback; a --params-file that does not exist is one error line and exit 2."""

import signal
import subprocess
import time
from pathlib import Path

import pytest
import rclpy
from ament_index_python.packages import get_package_prefix
from rclpy.executors import SingleThreadedExecutor

from quad_bringup.emulated.vehicle_graph import PORT_TAKEN, PORT_TRIES, WAIT_S, free_udp_port
from quad_common.ros.testing import isolated_domain

EXECUTABLES = [('quad_trajectory', 'trajectory_node', []), ('quad_control', 'position_controller', []),
               ('quad_sim', 'sim_node', []), ('quad_bridge', 'mavlink_bridge', ['fcu_url']),
               ('quad_bringup', 'recorder', ['output_dir'])]
SECOND_SIGINT_AFTER_S = 0.005


def _argv(package, executable, needs, tmp_path, name):
    argv = [str(Path(get_package_prefix(package)) / 'lib' / package / executable), '--ros-args',
            '-r', f'__node:={name}']
    if 'fcu_url' in needs:
        argv += ['-p', f'fcu_url:=udpin:127.0.0.1:{free_udp_port()}']
    if 'output_dir' in needs:
        argv += ['-p', f'output_dir:={tmp_path / "bag"}']
    return argv


def _wait_for_node(domain, name, proc):
    """Until `name` is in the graph, or the process exited (its status and output are then the caller's to judge:
    _ctrl_c_twice retries a bridge whose port was taken)."""
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain)
    node = rclpy.create_node('lifecycle_probe', context=ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    try:
        deadline = time.monotonic() + WAIT_S   # a hang guard only
        while name not in node.get_node_names() and proc.poll() is None:
            assert time.monotonic() < deadline, f'{name} never joined the graph'
            executor.spin_once(timeout_sec=0.05)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=ctx)


def _ctrl_c_twice(tmp_path, package, executable, needs, name, when_started):
    """_ctrl_c_once, on another claimed port when the bridge's fcu_url port was taken by a process that claims none
    (the bridge refused it, exit 2, before any signal mattered: CI saw it once on a machine other work shares)."""
    for _ in range(PORT_TRIES):
        code, out = _ctrl_c_once(tmp_path, package, executable, needs, name, when_started)
        if not (code == 2 and PORT_TAKEN in out and 'fcu_url' in needs):
            break
    return code, out


def _ctrl_c_once(tmp_path, package, executable, needs, name, when_started):
    """Starts the node, waits for when_started(domain, proc), sends SIGINT twice (as `ros2 launch` does on
    Ctrl-C) and returns (exit status, everything it printed)."""
    with isolated_domain() as (domain, env):
        proc = subprocess.Popen(_argv(package, executable, needs, tmp_path, name), env=env, text=True,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        try:
            first = when_started(domain, proc)
            proc.send_signal(signal.SIGINT)
            time.sleep(SECOND_SIGINT_AFTER_S)   # the second Ctrl-C of the scenario, not a synchronisation
            proc.send_signal(signal.SIGINT)
            out, _ = proc.communicate(timeout=WAIT_S)
        finally:
            proc.kill()
    return proc.returncode, first + out


@pytest.mark.parametrize('package,executable,needs', EXECUTABLES, ids=[e[1] for e in EXECUTABLES])
def test_a_second_sigint_during_shutdown_ends_the_node_cleanly(tmp_path, package, executable, needs):
    name = f'launched_{executable}'
    code, out = _ctrl_c_twice(tmp_path, package, executable, needs, name,
                              lambda domain, proc: _wait_for_node(domain, name, proc) or '')
    assert code == 0 and 'Traceback' not in out, out


STARTUP_LINE_EXECUTABLES = [e for e in EXECUTABLES if e[1] != 'trajectory_node']   # it logs nothing at start


@pytest.mark.parametrize('package,executable,needs', STARTUP_LINE_EXECUTABLES,
                         ids=[e[1] for e in STARTUP_LINE_EXECUTABLES])
def test_ctrl_c_while_the_node_is_still_starting_ends_it_cleanly(tmp_path, package, executable, needs):
    """Both SIGINTs right after the node's first log line, while its executor is still being built (CI saw a
    traceback, and -SIGINT from a signal arriving as the interpreter exits)."""
    code, out = _ctrl_c_twice(tmp_path, package, executable, needs, f'starting_{executable}',
                              lambda domain, proc: proc.stdout.readline())
    assert code == 0 and 'Traceback' not in out, out


# Extension modules the node's own imports load (after the console script's first line, quad_common.node_start):
# mapped into the process means start-up is at or past that import
IMPORTS = {'rclpy': '_rclpy_pybind11.', 'numpy': '_multiarray_umath.'}
POLL_S = 0.002   # how often /proc/<pid>/maps is read while waiting for a module (a condition, not a delay)


def _mapped(library):
    """when_started for _ctrl_c_twice: returns once `library` is mapped into the process."""
    def when_started(domain, proc):
        deadline = time.monotonic() + WAIT_S   # a hang guard only
        while library not in Path(f'/proc/{proc.pid}/maps').read_text():
            assert proc.poll() is None, f'exited with {proc.returncode} before loading {library}'
            assert time.monotonic() < deadline, f'{library} never loaded'
            time.sleep(POLL_S)
        return ''
    return when_started


@pytest.mark.parametrize('module', sorted(IMPORTS))
@pytest.mark.parametrize('package,executable,needs', EXECUTABLES, ids=[e[1] for e in EXECUTABLES])
def test_ctrl_c_while_the_node_imports_its_modules_ends_it_cleanly(tmp_path, package, executable, needs, module):
    """`ros2 launch` stopped in its first second: SIGINT while the console script still imports rclpy, numpy and
    the node's module (a KeyboardInterrupt traceback and exit -2 before quad_common.node_start)."""
    code, out = _ctrl_c_twice(tmp_path, package, executable, needs, f'importing_{executable}',
                              _mapped(IMPORTS[module]))
    assert code == 0 and 'Traceback' not in out, out


@pytest.mark.parametrize('package,executable,needs', EXECUTABLES, ids=[e[1] for e in EXECUTABLES])
def test_a_missing_params_file_is_one_line_and_exit_2(tmp_path, package, executable, needs):
    missing = tmp_path / 'no_such_params.yaml'
    with isolated_domain() as (_, env):
        proc = subprocess.run([*_argv(package, executable, needs, tmp_path, executable), '--params-file',
                               str(missing)], env=env, capture_output=True, text=True, timeout=WAIT_S)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 2, out
    assert 'Traceback' not in out and str(missing) in out and 'refused to start' in out
