"""Graph tests: `./quadflight fly` flies a short mission end to end in the lockstep simulator."""

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
import yaml
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

from quad_bringup.analysis.report import Completion, metrics_table, write_report

ROOT = Path(__file__).resolve().parents[2]
QUADFLIGHT = str(ROOT / 'quadflight')
TIMEOUT_S = 540


def mission(tmp_path, waypoints, speed=0.5, extra=''):
    path = tmp_path / 'short.yaml'
    path.write_text(f'name: short\nvehicle: {ROOT / "config/vehicles/crazyflie.yaml"}\n'
                    f'waypoints: {waypoints}\nyaw: 0.0\n'
                    f'trajectory:\n  method: minsnap\n  waypoint_constraint: continuity\n  speed: {speed}\n'
                    f'  time_allocation: sqrt\n{extra}')
    return path


def alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def test_fly_short_mission_end_to_end(tmp_path, ros_env):
    run_dir = tmp_path / 'run'
    path = mission(tmp_path, [[0, 0, 1], [0.8, 0.4, 1.2], [1.5, 0, 1]])
    done = subprocess.run([QUADFLIGHT, 'fly', str(path), '--out', str(run_dir), '--quiet'],
                          env=dict(ros_env, QUADFLIGHT_TIMING='1'), capture_output=True, text=True, timeout=TIMEOUT_S)
    assert done.returncode == 0, done.stdout + done.stderr
    # node_host is forked from fly (it inherits fly's imports: pools.forked); the figures' process imports once
    # the flight is under way (its imports then do not slow the start-up), and draws every figure
    phases = [line.split('] ', 1)[1] for line in done.stderr.splitlines() if line.startswith('[')]
    assert 'processes started (forked: node_host)' in phases, phases
    assert phases.index('figure worker importing') == \
        phases.index('flight started (plan and odometry at the monitor and in the bag)') + 1, phases
    assert len(list((run_dir / 'figures').glob('*.png'))) == 6
    metrics = json.loads((run_dir / 'metrics.json').read_text())
    assert metrics['completed'] is True and metrics['collided'] is False
    assert metrics['rmse_m'] < 0.03 and metrics['max_error_m'] < 0.06
    assert abs(metrics['time_actual_s'] - metrics['time_planned_s']) < 1.0
    assert metrics['length_actual_m'] == pytest.approx(metrics['length_planned_m'], abs=0.1)
    assert metrics['waypoint_miss_max_m'] < 0.05
    # what fly printed is the report's table of metrics.json
    assert metrics_table(metrics) in done.stdout
    # the report of the bag, computed again, equals what fly wrote and printed
    again = write_report(run_dir / 'bag', tmp_path / 'again', {k: metrics[k] for k in
                                                                 ('mission', 'controller', 'speed_mps', 'outcome')},
                         Completion(**metrics['completion_rule']))   # the vehicle's rule, as fly used it
    assert metrics['completion_rule']['source'] == 'vehicle crazyflie'
    assert again == metrics
    # the bag, read with rosbags alone
    ts = get_typestore(Stores.ROS2_JAZZY)
    with Reader(run_dir / 'bag') as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        odom = [c for c in reader.connections if c.topic == 'odom']
        last = None
        for c, _, raw in reader.messages(connections=odom):
            last = ts.deserialize_cdr(raw, c.msgtype)
    assert counts['trajectory'] == 1
    assert counts['odom'] >= 100 * metrics['time_actual_s']  # 100 Hz lockstep
    assert counts['cmd/attitude_thrust'] >= 100 * metrics['time_actual_s']
    p = last.pose.pose.position
    assert [p.x, p.y, p.z] == pytest.approx([1.5, 0.0, 1.0], abs=0.03)
    pids = json.loads((run_dir / 'pids.json').read_text())
    assert set(pids) == {'node_host'}   # the recorder, trajectory_node, sim_node and position_controller in one
    host_log = (run_dir / 'logs' / 'node_host.log').read_text()
    assert all(f'[{name}]' in host_log for name in ('recorder', 'trajectory_node', 'sim_node', 'position_controller'))
    assert 'bag closed: ' in host_log, host_log
    assert not any(alive(pid) for pid in pids.values())
    # nothing lost: every step sim_node published is in the bag, and the line fly printed says so
    record = metrics['record']
    assert record['complete'] and record['gaps'] == [] and 'missing' not in record
    assert record['odom_recorded'] == record['/clock_recorded'] == record['steps_published'] > 100
    n = record['steps_published']
    assert f'record: odom {n} and /clock {n} of {n} steps published by sim_node' in done.stdout
    assert 'record:' in (run_dir / 'report.md').read_text()
    # the verdict and the table come from the same samples: "completed at t = X" is the table's time actual
    assert f'completed at t = {metrics["time_actual_s"]:.2f} s' in done.stdout + done.stderr


def test_fly_from_the_motion_capture_stand_in(tmp_path, ros_env):
    """--state-source external_pose: the controller flies from the simulator's motion-capture stand-in (a frame per
    step, 1 mm), not from odometry; the flight completes close to the plan and the bag holds the poses flown from."""
    run_dir = tmp_path / 'run'
    path = mission(tmp_path, [[0, 0, 1], [0.8, 0.4, 1.2], [1.5, 0, 1]])
    done = subprocess.run([QUADFLIGHT, 'fly', str(path), '--out', str(run_dir), '--quiet',
                           '--state-source', 'external_pose'], env=ros_env, capture_output=True, text=True,
                          timeout=TIMEOUT_S)
    assert done.returncode == 0, done.stdout + done.stderr
    params = yaml.safe_load((run_dir / 'params.yaml').read_text())
    assert params['position_controller']['ros__parameters']['state_source'] == 'external_pose'
    assert params['sim_node']['ros__parameters']['mocap_rate_hz'] == 100.0
    metrics = json.loads((run_dir / 'metrics.json').read_text())
    assert metrics['completed'] is True and metrics['rmse_m'] < 0.03
    with Reader(run_dir / 'bag') as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert counts['external/pose'] >= 100 * metrics['time_actual_s']


def test_bad_mission_is_refused_before_anything_starts(tmp_path, ros_env):
    path = mission(tmp_path, [[0, 0, 1], [1, 0, 1]], extra='  speeed: 2.0\n')
    run_dir = tmp_path / 'run'
    done = subprocess.run([QUADFLIGHT, 'fly', str(path), '--out', str(run_dir)], env=ros_env,
                          capture_output=True, text=True, timeout=TIMEOUT_S)
    assert done.returncode == 2
    assert 'speeed' in done.stderr and str(path) in done.stderr
    assert not run_dir.exists()


def _start_fly(tmp_path, ros_env, waypoints, speed=0.5, extra_args=()):
    run_dir = tmp_path / 'run'
    path = mission(tmp_path, waypoints, speed=speed)
    proc = subprocess.Popen([QUADFLIGHT, 'fly', str(path), '--out', str(run_dir), *extra_args], env=ros_env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    return proc, run_dir


def _await_progress(proc, t_s):
    """Reads fly's output until a progress line past t_s (simulated): the flight is under way."""
    seen = []
    for line in proc.stdout:
        seen.append(line)
        if line.startswith('t = ') and float(line.split()[2]) > t_s:
            return seen
    raise AssertionError('fly ended before the flight was under way:\n' + ''.join(seen))


def _await_dead(pids, give_up_s=60.0):
    """Polls until none of pids exists (the exit of a process we are not the parent of is not awaitable)."""
    deadline = time.monotonic() + give_up_s
    while any(alive(p) for p in pids):
        assert time.monotonic() < deadline, f'still alive: {[p for p in pids if alive(p)]}'
        time.sleep(0.05)


SQUARE = [[0, 0, 1], [2, 0, 1], [2, 2, 1], [0, 2, 1], [0, 0, 1]]


def test_sigkill_of_fly_leaves_no_node_behind(tmp_path, ros_env):
    """Children get SIGTERM from the kernel when fly dies (PR_SET_PDEATHSIG, a parent watch as fallback): the
    recorder closes its bag; nothing runs on under init."""
    proc, run_dir = _start_fly(tmp_path, ros_env, SQUARE)
    try:
        _await_progress(proc, 1.0)
        pids = json.loads((run_dir / 'pids.json').read_text())
        assert pids and all(alive(p) for p in pids.values())
        proc.kill()
        proc.wait(timeout=TIMEOUT_S)
        _await_dead(list(pids.values()))
    finally:
        if proc.poll() is None:
            proc.kill()
    with Reader(run_dir / 'bag') as reader:  # closed by the recorder itself: metadata.yaml written
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert counts['odom'] > 100 and counts['trajectory'] == 1


@pytest.mark.parametrize('signum', [signal.SIGINT, signal.SIGHUP])
def test_signal_mid_flight_stops_everything_and_keeps_a_readable_bag(tmp_path, ros_env, signum):
    """Ctrl-C, and a closed terminal's SIGHUP alike: every node stopped, the bag closed, the report written."""
    proc, run_dir = _start_fly(tmp_path, ros_env, SQUARE)
    try:
        _await_progress(proc, 1.0)
        proc.send_signal(signum)
        out = proc.communicate(timeout=TIMEOUT_S)[0]
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, out
    assert f'interrupted by {signal.Signals(signum).name}' in out
    pids = json.loads((run_dir / 'pids.json').read_text())
    assert not any(alive(pid) for pid in pids.values())
    with Reader(run_dir / 'bag') as reader:  # closed cleanly: metadata.yaml written
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert counts['odom'] > 100 and counts['trajectory'] == 1
    metrics = json.loads((run_dir / 'metrics.json').read_text())
    assert metrics['completed'] is False and metrics['record']['complete'] is True
    assert metrics['time_actual_s'] < metrics['time_planned_s']
    assert (run_dir / 'report.md').exists()


def test_dead_controller_lets_the_failsafe_land_and_fly_says_where(tmp_path, ros_env):
    """--process-per-node (each node a process, as launch_ros starts them): SIGKILL of position_controller
    mid-flight: the graph runs on until sim_node's failsafe has landed, the bag shows the landing, and fly names
    what died, when and where the vehicle came down (near where it was)."""
    # a long leg (~40 s simulated): fly prints progress once a wall second, and a lockstep flight on an idle
    # machine runs ~14x real time, so a short one could end before the first progress line
    proc, run_dir = _start_fly(tmp_path, ros_env, [[0, 0, 1], [20, 0, 1]], speed=0.5,
                               extra_args=['--process-per-node'])
    try:
        _await_progress(proc, 2.0)
        pids = json.loads((run_dir / 'pids.json').read_text())
        assert set(pids) == {'trajectory_node', 'position_controller', 'sim_node', 'recorder'}
        os.kill(pids['position_controller'], signal.SIGKILL)
        out = proc.communicate(timeout=TIMEOUT_S)[0]
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 1, out
    assert 'fault: position_controller died at t = ' in out and 'the failsafe landed the vehicle' in out, out
    metrics = json.loads((run_dir / 'metrics.json').read_text())
    fault = metrics['fault']
    assert fault['node'] == 'position_controller' and fault['landed'] is True
    ts = get_typestore(Stores.ROS2_JAZZY)
    with Reader(run_dir / 'bag') as reader:
        odom = [c for c in reader.connections if c.topic == 'odom']
        positions = [ts.deserialize_cdr(raw, c.msgtype).pose.pose.position for c, _, raw in reader.messages(odom)]
    last = positions[-1]
    assert last.z == pytest.approx(0.0, abs=0.01)                         # the bag shows it on the floor
    assert fault['landed_position_m'] == pytest.approx([last.x, last.y, last.z], abs=0.05)
    assert 0.0 < last.x < 20.0 and abs(last.y) < 0.3                      # near the line it flew, not drifted off


@pytest.mark.parametrize('args, words', [
    (['--position-tolerance', '-1'], ['--position-tolerance', '-1']),
    (['--time-limit-factor', '0'], ['--time-limit-factor', '0']),
    (['--speed-tolerance', 'nan'], ['--speed-tolerance', 'nan']),
    (['--speed', '-2'], ['--speed', '-2']),
])
def test_bad_option_refused_with_its_range_before_anything_starts(tmp_path, ros_env, args, words):
    path = mission(tmp_path, [[0, 0, 1], [1, 0, 1]])
    run_dir = tmp_path / 'run'
    done = subprocess.run([QUADFLIGHT, 'fly', str(path), '--out', str(run_dir), *args], env=ros_env,
                          capture_output=True, text=True, timeout=TIMEOUT_S)
    assert done.returncode == 2, done.stdout + done.stderr
    assert all(w in done.stderr for w in words) and 'must be > ' in done.stderr
    assert 'Traceback' not in done.stderr and not run_dir.exists()


@pytest.mark.parametrize('command', ['fly', 'plan'])
@pytest.mark.parametrize('out', ['/proc/quadflight-run', 'FILE/under-a-file'])
def test_unwritable_out_is_one_clear_line(tmp_path, ros_env, command, out):
    path = mission(tmp_path, [[0, 0, 1], [1, 0, 1]])
    (tmp_path / 'FILE').write_text('a file, not a directory')
    out = out.replace('FILE', str(tmp_path / 'FILE'))
    target = out if command == 'fly' else f'{out}/traj.json'
    done = subprocess.run([QUADFLIGHT, command, str(path), '--out', target], env=ros_env,
                          capture_output=True, text=True, timeout=TIMEOUT_S)
    assert done.returncode == 2, done.stdout + done.stderr
    assert 'Traceback' not in done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and '--out' in lines[0] and out in lines[0], done.stderr


def test_a_second_fly_on_a_flying_out_is_refused_and_the_first_flies_on(tmp_path, ros_env):
    """Two flies on one --out: the second is refused before it starts anything (exit 2, naming the first's pid),
    and the first's flight, bag and logs are its own."""
    path = mission(tmp_path, [[0, 0, 1], [1.0, 0.3, 1.1], [1.5, 0, 1]])
    run_dir = tmp_path / 'run'
    first = subprocess.Popen([QUADFLIGHT, 'fly', str(path), '--out', str(run_dir)], env=ros_env,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        for line in first.stdout:   # said once the run directory is fly's and before its nodes start
            if line.startswith('flying '):
                break
        second = subprocess.run([QUADFLIGHT, 'fly', str(path), '--out', str(run_dir)], env=ros_env,
                                capture_output=True, text=True, timeout=TIMEOUT_S)
        out, err = first.communicate(timeout=TIMEOUT_S)
    finally:
        first.kill()
        first.wait()
    assert second.returncode == 2, second.stdout + second.stderr
    assert f'--out {run_dir}: another command writes there now (fly pid {first.pid})' in second.stderr
    assert first.returncode == 0, out + err
    assert not (run_dir / 'bag.repaired').exists()
    assert json.loads((run_dir / 'metrics.json').read_text())['completed'] is True


def test_run_directories_are_unique_under_a_race(tmp_path):
    """Default run directories: many flies starting in the same millisecond each get their own."""
    from concurrent.futures import ThreadPoolExecutor

    from quad_bringup.running.flight_options import make_run_dir
    default = tmp_path / 'runs' / 'maze-pd-20260101-000000-000'
    with ThreadPoolExecutor(8) as pool:
        made = list(pool.map(lambda _: make_run_dir(None, default), range(16)))
    assert len(set(made)) == 16 and all(d.is_dir() for d in made)
    assert default in made and default.with_name(default.name + '-2') in made
