"""The environment itself: rclpy over DDS between processes, and --params-file."""

import json
import subprocess
import sys
import textwrap

import pytest

PUBLISHER = textwrap.dedent('''
    import rclpy
    from nav_msgs.msg import Odometry
    rclpy.init()
    node = rclpy.create_node('odom_talker')
    pub = node.create_publisher(Odometry, 'odom', 10)
    msg = Odometry()
    msg.header.frame_id = 'map'
    msg.pose.pose.position.x = 1.25
    node.create_timer(0.05, lambda: pub.publish(msg))
    rclpy.spin(node)
''')

SUBSCRIBER = textwrap.dedent('''
    import rclpy
    from nav_msgs.msg import Odometry
    rclpy.init()
    node = rclpy.create_node('odom_listener')
    got = []
    node.create_subscription(Odometry, 'odom', got.append, 10)
    while not got:
        rclpy.spin_once(node, timeout_sec=1.0)
    print(got[0].header.frame_id, got[0].pose.pose.position.x, flush=True)
''')

PARAM_READER = textwrap.dedent('''
    import json, sys
    import rclpy
    rclpy.init(args=sys.argv)
    node = rclpy.create_node('reader')
    names = {'rate_hz': 1.0, 'gains': [0.0], 'mode': ''}
    print(json.dumps({k: node.declare_parameter(k, v).value for k, v in names.items()}))
''')


def test_odometry_crosses_processes_over_dds(ros_env):
    pub = subprocess.Popen([sys.executable, '-c', PUBLISHER], env=ros_env)
    try:
        out = subprocess.run([sys.executable, '-c', SUBSCRIBER], env=ros_env, capture_output=True,
                             text=True, timeout=60, check=True).stdout
    finally:
        pub.terminate()
        pub.wait(timeout=10)
    assert out.split() == ['map', '1.25']


def test_node_reads_params_file(ros_env, tmp_path):
    params = tmp_path / 'params.yaml'
    params.write_text('reader:\n  ros__parameters:\n    rate_hz: 250.0\n    gains: [5.0, 5.0, 20.0]\n'
                      '    mode: lockstep\n')
    out = subprocess.run([sys.executable, '-c', PARAM_READER, '--ros-args', '--params-file', str(params)],
                         env=ros_env, capture_output=True, text=True, timeout=60, check=True).stdout
    assert json.loads(out) == {'rate_hz': 250.0, 'gains': [5.0, 5.0, 20.0], 'mode': 'lockstep'}


@pytest.mark.parametrize('failing', ['SUITE_FIRST', 'SUITE_BESIDE', 'SUITE_MAIN'])
def test_make_test_runs_every_suite_and_sums_up(tmp_path, failing):
    """`make test` goes on after a failing suite (lint first, then the package tests beside the graph tests), ends
    with one summary and fails if any suite failed."""
    from pathlib import Path
    root = Path(__file__).resolve().parents[2]
    probes = tmp_path / 'probes.mk'
    probes.write_text(f'probe-fail:\n\tfalse\nprobe-ok-%:\n\ttouch {tmp_path}/ran-$*\n')
    suites = {slot: f'probe-ok-{slot}' for slot in ('SUITE_FIRST', 'SUITE_BESIDE', 'SUITE_MAIN')}
    suites[failing] = 'probe-fail'
    done = subprocess.run(['make', '--no-print-directory', '-C', str(root), '-f', 'Makefile', '-f', str(probes),
                           'test', *(f'{k}={v}' for k, v in suites.items()), 'BUILD_STAMP=',
                           f'BESIDE_LOG={tmp_path}/beside.log'], capture_output=True, text=True, timeout=120)
    assert done.returncode != 0
    ran = {p.name for p in tmp_path.glob('ran-*')}
    assert ran == {f'ran-{slot}' for slot in suites if slot != failing}   # every other suite ran
    assert done.stdout.strip().splitlines()[-1] == '=== summary: 3 suites, probe-fail failed'


SHARED_FIXTURE_TESTS = textwrap.dedent('''
    import os
    import pytest

    @pytest.fixture(scope='module')
    def shared():
        with open(os.environ['SETUPS_LOG'], 'a') as log:
            log.write('setup\\n')

    @pytest.mark.parametrize('n', range(4))
    def test_shares(shared, n):
        with open(os.environ['SETUPS_LOG'], 'a') as log:
            log.write(f"shared {os.environ['PYTEST_XDIST_WORKER']}\\n")

    @pytest.mark.parametrize('n', range(4))
    def test_alone(n):
        pass
''')


def test_loadgroup_runs_a_files_shared_fixture_once(tmp_path):
    """test-graph's --dist loadgroup (xdist_groups, through conftest): a file's tests that share a module fixture run
    on one worker, which sets it up once; a pytest or pytest-xdist that loses the group fails here."""
    import os
    from pathlib import Path
    (tmp_path / 'conftest.py').write_text('from xdist_groups import pytest_collection_modifyitems  # noqa: F401\n')
    (tmp_path / 'test_shared_fixture.py').write_text(SHARED_FIXTURE_TESTS)
    log = tmp_path / 'setups.log'
    env = dict(os.environ, SETUPS_LOG=str(log),
               PYTHONPATH=os.pathsep.join([str(Path(__file__).parents[1]), os.environ.get('PYTHONPATH', '')]))
    done = subprocess.run([sys.executable, '-m', 'pytest', '-q', '-p', 'no:cacheprovider', '-n', '2',
                           '--dist', 'loadgroup', '--rootdir', str(tmp_path), str(tmp_path)],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
    lines = log.read_text().splitlines()
    assert lines.count('setup') == 1 and len(set(line for line in lines if line != 'setup')) == 1, lines
