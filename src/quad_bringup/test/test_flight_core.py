"""fly's judgement of a flight, its wait for the recorder, and its stopping of process groups."""

import os
import sys
import textwrap
import time

import numpy as np
import pytest
import rclpy
from nav_msgs.msg import Odometry

from quad_bringup.analysis.report import Completion
from quad_bringup.running import processes
from quad_bringup.running.flight_monitor import FlightJudge, FlightMonitor
from quad_common.ros.testing import isolated_domain
from quad_common.sampled_trajectory import SampledTrajectory


def straight_plan(duration_s=2.0, length_m=1.0):
    t = np.linspace(0, duration_s, 201)
    s = t / duration_s
    x = length_m * (10 * s ** 3 - 15 * s ** 4 + 6 * s ** 5)
    pos = np.zeros((t.size, 4))
    pos[:, 0], pos[:, 2] = x, 1.0
    return SampledTrajectory(t, pos, np.zeros_like(pos), np.zeros_like(pos))


def judge_with_plan(**kwargs):
    judge = FlightJudge(Completion(), **kwargs)
    judge.set_trajectory(100.0, straight_plan())
    return judge


def test_completion_needs_the_planned_end_tolerance_and_a_hold():
    judge = judge_with_plan(hold_after_completion_s=0.5)
    at_end, still = np.array([1.0, 0.0, 1.0]), np.zeros(3)
    judge.on_odometry(101.0, np.array([0.5, 0, 1.0]), still)  # mid-flight, on the plan
    assert judge.verdict is None and judge.error_m == pytest.approx(0.0)
    judge.on_odometry(102.0, at_end + [0.03, 0, 0], still)     # after the end but 3 cm off
    judge.on_odometry(102.1, at_end + [0.01, 0, 0], np.array([0.05, 0, 0]))  # close but too fast
    assert judge.completed_at_s is None
    judge.on_odometry(102.2, at_end + [0.01, 0, 0], still)
    assert judge.completed_at_s == pytest.approx(2.2) and judge.verdict is None
    judge.on_odometry(102.7, at_end, still)
    assert judge.verdict.ok and 'completed at t = 2.20 s' in judge.verdict.reason


def test_divergence_collision_and_time_limit():
    judge = judge_with_plan(divergence_m=0.5)
    judge.on_odometry(100.5, np.array([0.0, 0.6, 1.0]), np.zeros(3))
    assert not judge.verdict.ok and 'diverged' in judge.verdict.reason
    judge = judge_with_plan()
    judge.on_collision(101.25, 'hit block 3')
    assert not judge.verdict.ok and judge.verdict.reason == 'collision at t = 1.25 s: hit block 3'
    judge = judge_with_plan(time_limit_factor=2.0, time_limit_margin_s=1.0)
    judge.on_odometry(104.9, np.array([1.0, 0.1, 1.0]), np.zeros(3))
    assert judge.verdict is None
    judge.on_odometry(105.1, np.array([1.0, 0.1, 1.0]), np.zeros(3))
    assert not judge.verdict.ok and 'time limit' in judge.verdict.reason


STUBBORN = textwrap.dedent('''
    import signal, subprocess, sys, time
    signal.signal(signal.SIGINT, signal.SIG_IGN)          # ignores Ctrl-C
    child = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(600)'])  # and has a child
    print(child.pid, flush=True)
    time.sleep(600)
''')


def test_stop_escalates_and_leaves_no_process_of_the_group(tmp_path):
    proc = processes.NodeProcess('stubborn', 'unused', [], tmp_path / 'stubborn.log')
    proc.command = lambda: [sys.executable, '-c', STUBBORN]
    proc.start(dict(os.environ))
    while not proc.log_path.read_text().strip():  # the grandchild exists once its pid is printed
        assert proc.exit_code() is None
    lines = []
    codes = processes.stop([proc], grace_s=1.0, log=lines.append)
    assert codes['stubborn'] == -15  # SIGINT ignored, SIGTERM ended it
    assert lines == ['stubborn still running: sending SIGTERM']
    grandchild = int(proc.log_path.read_text().split()[0])
    for _ in range(200):
        if not processes.group_alive(proc.pid):
            break
        __import__('time').sleep(0.05)
    assert not processes.group_alive(proc.pid)
    with pytest.raises(ProcessLookupError):
        os.kill(grandchild, 0)


def test_monitor_sees_which_topics_a_node_reads_before_the_graph_starts():
    """fly starts the graph only once the recorder's readers are on it (else a short flight outruns the bag)."""
    with isolated_domain() as (domain, _):
        monitor = FlightMonitor(domain, judge_with_plan())
        ctx = rclpy.Context()
        rclpy.init(context=ctx, domain_id=domain)
        recorder = rclpy.create_node('recorder', context=ctx)
        try:
            assert monitor.missing_readers('recorder', ['odom', 'trajectory']) == ['odom', 'trajectory']
            recorder.create_subscription(Odometry, 'odom', lambda msg: None, 10)
            deadline = time.monotonic() + 30
            while monitor.missing_readers('recorder', ['odom', 'trajectory']) != ['trajectory']:
                assert time.monotonic() < deadline, 'the recorder subscription never showed on the graph'
                monitor.spin_once(0.05)
            # the monitor's own reader on trajectory is not the recorder's
            assert monitor.missing_readers('recorder', ['/trajectory']) == ['/trajectory']
        finally:
            recorder.destroy_node()
            rclpy.shutdown(context=ctx)
            monitor.close()
