"""realtime_priority (docs/bridge.md "Real-time scheduling"): the bridge process with every thread under SCHED_FIFO,
Fast DDS's and those it starts later included; the system's refusal said loudly, naming the parameter and how to
grant it, the bridge running on; a priority outside 0..99 refused at start-up naming the field and the value.
position_controller started as the px4 launch file starts it (its control_real.yaml sets 20): every thread but the
trajectory decoder's under SCHED_FIFO; refused: said, and it runs on."""

import os
import selectors
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from ament_index_python.packages import get_package_prefix
from launch_standin import evaluate

from quad_bringup.emulated.vehicle_graph import Observer, free_udp_port, python_env, terminate
from quad_common.realtime import policy_of, thread_ids

BRIDGE = [sys.executable, '-m', 'quad_bridge.mavlink_bridge_node', '--ros-args']
NAMESPACE = f'/bridge_realtime_{os.getpid()}'
ROOT = Path(__file__).resolve().parents[2]
DROP_SYS_NICE = ['setpriv', '--inh-caps=-sys_nice', '--bounding-set=-sys_nice', 'prlimit', '--rtprio=0', '--']


def _policies(pid) -> dict:
    """{tid: (policy, priority)} of every thread of the process (one that ended meanwhile left out)."""
    out = {}
    for tid in thread_ids(pid):
        try:
            out[tid] = policy_of(tid)
        except ProcessLookupError:
            pass
    return out


def _started(ros_env, priority, prefix=()):
    """A bridge (no vehicle on its port) until it says it started: (process, its log so far)."""
    args = [*prefix, *BRIDGE, '-p', f'fcu_url:=udpin:127.0.0.1:{free_udp_port()}', '-p',
            f'realtime_priority:={priority}', '-r', f'__ns:={NAMESPACE}']
    return _until_said(args, ros_env, 'keep-alive')


def _until_said(args, ros_env, said):
    """The process of args until its log says `said` (or it ends; a hang guard of 60 s): (process, its log)."""
    proc = subprocess.Popen(args, env=python_env(ros_env), stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    log, deadline = '', time.monotonic() + 60.0
    with selectors.DefaultSelector() as sel:
        sel.register(proc.stdout, selectors.EVENT_READ)
        while said not in log and time.monotonic() < deadline and proc.poll() is None:
            if sel.select(timeout=1.0):   # all that is in the pipe: a readline would leave a second line, written
                chunk = os.read(proc.stdout.fileno(), 65536)   # with the first, in a buffer select does not see
                if not chunk:
                    break
                log += chunk.decode(errors='replace')
    return proc, log


def _controller_started(ros_env, tmp_path, prefix=()):
    """position_controller as px4.launch.py starts it (installed console script, its params files) until it says
    how it is scheduled (no namespace: the profile's `position_controller:` section is for /position_controller;
    ros_env's domain is the test's own)."""
    node = next(n for n in evaluate(ROOT / 'src' / 'quad_bringup' / 'launch' / 'px4.launch.py')
                if n.executable == 'position_controller')
    argv = node.command(tmp_path, Path(get_package_prefix(node.package)))
    return _until_said([*prefix, *argv], ros_env, 'scheduling')


def _drop_sys_nice() -> list:
    """A command prefix under which the kernel refuses SCHED_FIFO: no CAP_SYS_NICE, RLIMIT_RTPRIO 0."""
    return DROP_SYS_NICE if shutil.which('prlimit') else DROP_SYS_NICE[:3]


def _said_in_diagnostics(ros_env) -> str:
    """`realtime` of the bridge's `mavlink_bridge: link` status (published once a second, vehicle or not)."""
    observer = Observer(int(ros_env['ROS_DOMAIN_ID']), NAMESPACE)
    try:
        deadline = time.monotonic() + 30.0
        while 'realtime' not in observer.link()[1] and time.monotonic() < deadline:
            time.sleep(0.2)
        return observer.link()[1].get('realtime', '')
    finally:
        observer.close()


@pytest.mark.skipif(os.geteuid() != 0, reason='SCHED_FIFO needs root or CAP_SYS_NICE here')
def test_every_thread_of_the_bridge_runs_under_sched_fifo_at_the_priority(ros_env):
    proc, log = _started(ros_env, 7)
    try:
        assert proc.poll() is None, log
        # its diagnostics come from the supervisor thread, the last one it starts: every thread is up by then
        assert _said_in_diagnostics(ros_env).startswith('SCHED_FIFO 7 (')
        policies = _policies(proc.pid)
        # the executor's, Fast DDS's (created before the node was), the receive, setpoint and supervisor threads
        assert len(policies) >= 6, policies
        assert set(policies.values()) == {(os.SCHED_FIFO, 7)}, policies
        assert 'scheduling SCHED_FIFO 7' in log
    finally:
        terminate(proc)


def test_off_by_default_leaves_the_ordinary_scheduler(ros_env):
    proc, log = _started(ros_env, 0)
    try:
        assert proc.poll() is None, log
        assert {policy for policy, _ in _policies(proc.pid).values()} == {os.SCHED_OTHER}
        assert 'scheduling off' in log
    finally:
        terminate(proc)


@pytest.mark.skipif(os.geteuid() != 0 or not shutil.which('setpriv'), reason='needs root and setpriv to drop a '
                    'capability')
def test_a_refused_realtime_priority_is_an_error_naming_the_parameter_and_the_bridge_runs_on(ros_env):
    """Without CAP_SYS_NICE and with RLIMIT_RTPRIO 0 the kernel refuses SCHED_FIFO (EPERM)."""
    proc, log = _started(ros_env, 20, _drop_sys_nice())
    try:
        assert proc.poll() is None, log
        assert '[ERROR]' in log and 'realtime_priority = 20: SCHED_FIFO refused' in log, log
        for how in ('CAP_SYS_NICE', 'ulimit -r', 'rtprio', 'realtime_priority: 0'):
            assert how in log, (how, log)
        assert {policy for policy, _ in _policies(proc.pid).values()} == {os.SCHED_OTHER}
        assert _said_in_diagnostics(ros_env).startswith('refused: realtime_priority = 20: SCHED_FIFO refused')
    finally:
        terminate(proc)


@pytest.mark.parametrize('value', ['-1', '100'])
def test_a_priority_outside_0_to_99_is_refused_at_start_up_naming_the_field_and_the_value(ros_env, value):
    out = subprocess.run([*BRIDGE, '-p', f'realtime_priority:={value}'], env=python_env(ros_env),
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2, out.stderr
    said = out.stderr + out.stdout
    assert 'refused to start: parameter realtime_priority' in said and f'Min: 0, Max: 99, value: {value}' in said


@pytest.mark.skipif(os.geteuid() != 0, reason='SCHED_FIFO needs root or CAP_SYS_NICE here')
def test_position_controller_as_the_px4_launch_starts_it_runs_its_tick_under_sched_fifo(ros_env, tmp_path):
    proc, log = _controller_started(ros_env, tmp_path)
    try:
        assert proc.poll() is None, log
        assert 'scheduling SCHED_FIFO 20' in log, log      # config/control_real.yaml
        policies = list(_policies(proc.pid).values())
        # the executor's (the tick's) and Fast DDS's threads; the trajectory decoder alone ordinary
        assert policies.count((os.SCHED_OTHER, 0)) == 1 and len(policies) >= 5, policies
        assert set(policies) == {(os.SCHED_FIFO, 20), (os.SCHED_OTHER, 0)}, policies
    finally:
        terminate(proc)


@pytest.mark.skipif(os.geteuid() != 0 or not shutil.which('setpriv'), reason='needs root and setpriv to drop a '
                    'capability')
def test_position_controller_refused_realtime_says_so_and_runs_on(ros_env, tmp_path):
    proc, log = _controller_started(ros_env, tmp_path, _drop_sys_nice())
    try:
        assert proc.poll() is None, log
        assert '[ERROR]' in log and 'realtime_priority = 20: SCHED_FIFO refused' in log, log
        assert 'scheduling refused: realtime_priority = 20' in log, log
        assert {policy for policy, _ in _policies(proc.pid).values()} == {os.SCHED_OTHER}
    finally:
        terminate(proc)
