"""Graph tests: `./quadflight fly` flies a short mission end to end in the lockstep simulator."""

import importlib.util
import json
import os
import signal
import subprocess
from pathlib import Path

import pytest
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

from quad_bringup.report import Completion, metrics_table, write_report

ROOT = Path(__file__).resolve().parents[1]
QUADFLIGHT = str(ROOT / 'quadflight')
TIMEOUT_S = 540
needs_graph = pytest.mark.skipif(importlib.util.find_spec('quad_trajectory.trajectory_node') is None,
                                 reason='trajectory_node is not merged yet')


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


@needs_graph
def test_fly_short_mission_end_to_end(tmp_path, ros_env):
    run_dir = tmp_path / 'run'
    path = mission(tmp_path, [[0, 0, 1], [0.8, 0.4, 1.2], [1.5, 0, 1]])
    done = subprocess.run([QUADFLIGHT, 'fly', str(path), '--out', str(run_dir), '--quiet'], env=ros_env,
                          capture_output=True, text=True, timeout=TIMEOUT_S)
    assert done.returncode == 0, done.stdout + done.stderr
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
    assert set(pids) == {'trajectory_node', 'position_controller', 'sim_node', 'recorder'}
    assert not any(alive(pid) for pid in pids.values())


@needs_graph
def test_sigint_mid_flight_stops_everything_and_keeps_a_readable_bag(tmp_path, ros_env):
    run_dir = tmp_path / 'run'
    path = mission(tmp_path, [[0, 0, 1], [2, 0, 1], [2, 2, 1], [0, 2, 1], [0, 0, 1]], speed=0.5)
    proc = subprocess.Popen([QUADFLIGHT, 'fly', str(path), '--out', str(run_dir)], env=ros_env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        for line in proc.stdout:  # progress lines once the simulated flight is under way
            if line.startswith('t = ') and float(line.split()[2]) > 1.0:
                break
        proc.send_signal(signal.SIGINT)
        out = proc.communicate(timeout=TIMEOUT_S)[0]
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, out
    assert 'interrupted by SIGINT' in out
    pids = json.loads((run_dir / 'pids.json').read_text())
    assert not any(alive(pid) for pid in pids.values())
    with Reader(run_dir / 'bag') as reader:  # closed cleanly: metadata.yaml written
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert counts['odom'] > 100 and counts['trajectory'] == 1
    metrics = json.loads((run_dir / 'metrics.json').read_text())
    assert metrics['completed'] is False
    assert metrics['time_actual_s'] < metrics['time_planned_s']


def test_bad_mission_is_refused_before_anything_starts(tmp_path, ros_env):
    path = mission(tmp_path, [[0, 0, 1], [1, 0, 1]], extra='  speeed: 2.0\n')
    run_dir = tmp_path / 'run'
    done = subprocess.run([QUADFLIGHT, 'fly', str(path), '--out', str(run_dir)], env=ros_env,
                          capture_output=True, text=True, timeout=TIMEOUT_S)
    assert done.returncode == 2
    assert 'speeed' in done.stderr and str(path) in done.stderr
    assert not run_dir.exists()
