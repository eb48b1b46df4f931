"""What a ROS 2 user runs, from a directory that is not the checkout: `ros2 run` (the installed console scripts) with
the file arguments docs and launch files use (`missions/maze.yaml`, `vehicles/px4_quad.yaml`: found by the one
lookup rule of quad_common.paths), and the emulated vehicle's MAVLink system id set by the autopilot's own
parameter (PX4 MAV_SYS_ID, ArduPilot SYSID_THISMAV), as a fleet file's bridges expect."""

import os
import shlex
import subprocess
from pathlib import Path

import pytest
from ament_index_python.packages import get_package_prefix
from launch_standin import evaluate
from launched_params import ParameterReader

from quad_bringup.emulated.vehicle_graph import WAIT_S, free_udp_port, terminate
from quad_common.ros.testing import isolated_domain

os.environ['MAVLINK20'] = '1'
from pymavlink import mavutil  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
LAUNCH = ROOT / 'src' / 'quad_bringup' / 'launch'


def ros2_run(package: str, executable: str, *args) -> list[str]:
    """The argv `ros2 run PACKAGE EXECUTABLE ARGS` runs."""
    return [os.path.join(get_package_prefix(package), 'lib', package, executable), *args]


@pytest.mark.parametrize('autopilot, param, system_id', [('px4', 'MAV_SYS_ID', 2), ('ardupilot', 'SYSID_THISMAV', 3)])
def test_emulated_vehicle_takes_its_system_id_from_the_autopilot_parameter(tmp_path, autopilot, param, system_id):
    """`ros2 run quad_vehicle_emu mavlink_vehicle ...` as docs/bridge.md writes it, outside the checkout (its default
    --vehicle is found in the installed config) with `--param MAV_SYS_ID=2`: its heartbeat comes from system 2,
    its PARAM_VALUE says 2, and it obeys only what targets system 2 (or 0)."""
    port = free_udp_port()
    gcs = mavutil.mavlink_connection(f'udpin:127.0.0.1:{port}', source_system=255, source_component=190)
    log = tmp_path / 'vehicle.log'
    with open(log, 'w') as out:
        proc = subprocess.Popen(ros2_run('quad_vehicle_emu', 'mavlink_vehicle', '--autopilot', autopilot, '--url',
                                         f'udpout:127.0.0.1:{port}', '--param', f'{param}={system_id}'),
                                cwd=tmp_path, stdout=out, stderr=subprocess.STDOUT)
    try:
        heartbeat = None
        while heartbeat is None:
            assert proc.poll() is None, log.read_text()
            heartbeat = gcs.recv_match(type='HEARTBEAT', blocking=True, timeout=1.0)
        assert heartbeat.get_srcSystem() == system_id, log.read_text()
        gcs.mav.param_request_read_send(system_id, 1, param.encode(), -1)
        value = None
        while value is None or value.param_id != param:
            assert proc.poll() is None, log.read_text()
            value = gcs.recv_match(type='PARAM_VALUE', blocking=True, timeout=WAIT_S)
            assert value is not None, f'no PARAM_VALUE of {param}'
            assert value.get_srcSystem() == system_id
    finally:
        terminate(proc)
        gcs.close()


def test_emulated_vehicle_refuses_a_system_id_option_that_disagrees_with_the_parameter(tmp_path):
    out = subprocess.run(ros2_run('quad_vehicle_emu', 'mavlink_vehicle', '--param', 'MAV_SYS_ID=2', '--system-id',
                                  '3', '--url', f'udpout:127.0.0.1:{free_udp_port()}'),
                         cwd=tmp_path, capture_output=True, text=True, timeout=WAIT_S)
    assert out.returncode == 2 and out.stderr.strip().splitlines() == [
        'mavlink_vehicle: --param MAV_SYS_ID=2.0 and its option (3) disagree: give one']


@pytest.mark.parametrize('node', ['trajectory_node', 'position_controller'])
def test_nodes_find_launch_style_file_arguments_from_any_directory(tmp_path, node):
    """-p mission_file:=missions/maze.yaml, vehicle_file / vehicle:=vehicles/px4_quad.yaml (what the launch
    arguments take) from a directory without config/: the nodes start (they answer their parameter services only
    once their start-up is done) with the files' absolute paths found in the config directory."""
    package, args = {'trajectory_node': ('quad_trajectory', ['-p', 'mission_file:=missions/maze.yaml', '-p',
                                                             'vehicle_file:=vehicles/px4_quad.yaml']),
                     'position_controller': ('quad_control', ['-p', 'vehicle:=vehicles/px4_quad.yaml'])}[node]
    log = tmp_path / f'{node}.log'
    with isolated_domain() as (domain, env):
        reader = ParameterReader(domain)
        with open(log, 'w') as out:
            proc = subprocess.Popen(ros2_run(package, node, '--ros-args', *args), env=env, cwd=tmp_path, stdout=out,
                                    stderr=subprocess.STDOUT)

        def alive():
            assert proc.poll() is None, log.read_text()
        try:
            params = reader.parameters(f'/{node}', alive)
        finally:
            terminate(proc)
            reader.close()
    assert (params.get('mission_file') or params.get('vehicle')) in ('missions/maze.yaml', 'vehicles/px4_quad.yaml')
    assert 'refused' not in log.read_text()


def test_a_missing_file_is_refused_naming_the_parameter_and_where_it_looked(tmp_path):
    with isolated_domain() as (_, env):
        out = subprocess.run(ros2_run('quad_trajectory', 'trajectory_node', '--ros-args', '-p',
                                      'mission_file:=missions/nowhere.yaml'),
                             env=env, cwd=tmp_path, capture_output=True, text=True, timeout=WAIT_S)
    assert out.returncode == 2
    text = out.stdout + out.stderr
    assert f"mission_file = 'missions/nowhere.yaml': missions/nowhere.yaml: no such file (looked in {tmp_path}/" \
           f'missions/nowhere.yaml, ' in text
    assert 'share/quad_bringup/config/missions/nowhere.yaml' in text and 'Traceback' not in text


def test_quadflight_plan_from_another_directory(tmp_path):
    """`ros2 run quad_bringup quadflight plan missions/maze.yaml`, as docs/missions.md names missions."""
    out = subprocess.run(ros2_run('quad_bringup', 'quadflight', 'plan', 'missions/maze.yaml', '--out', 'maze.json'),
                         cwd=tmp_path, capture_output=True, text=True, timeout=WAIT_S, env=dict(os.environ))
    assert out.returncode == 0, out.stderr
    assert (tmp_path / 'maze.json').is_file()


def _walk_through(doc: str, marker: str) -> list[str]:
    """The command lines of the code block after `marker` in docs/<doc>."""
    text = (ROOT / 'docs' / doc).read_text()
    block = text[text.index(marker):].split('```')[1]
    return [line.rstrip(' &') for line in block.strip().splitlines()]


def _copy_output(proc, log_path, words):
    """A thread copying proc's output lines to log_path; the event set at the first line holding `words` (and at
    the end of the output, so that a waiter never hangs on a dead process)."""
    import threading
    seen = threading.Event()

    def copy():
        with open(log_path, 'w') as log:
            for line in proc.stdout:
                log.write(line)
                log.flush()
                if words in line:
                    seen.set()
        seen.set()
    threading.Thread(target=copy, daemon=True).start()
    return seen


def test_docs_fleet_walk_through_each_bridge_finds_its_vehicle(tmp_path):
    """docs/bridge.md's fleet walk-through, line by line (ros2 run: the installed console script; ros2 launch: the
    launch file's nodes as launch_ros starts them), from a directory outside the checkout: each namespace's
    bridge hears its own vehicle (target_system = the fleet file's system_id = the emulator's MAV_SYS_ID /
    SYSID_THISMAV) and publishes its odometry, at that emulator's start position."""
    import time

    import rclpy
    from nav_msgs.msg import Odometry

    from quad_common import contract

    lines = _walk_through('bridge.md', '<!-- fleet walk-through')
    runs = [shlex.split(line) for line in lines if line.startswith('ros2 run ')]
    launches = [shlex.split(line) for line in lines if line.startswith('ros2 launch ')]
    assert len(runs) == 3 and launches == [['ros2', 'launch', 'quad_bringup', 'fleet.launch.py']]
    starts = {}
    for argv in runs:
        position = [float(v) for v in argv[argv.index('--initial-position') + 1].split(',')]
        starts[{'px4': None, 'ardupilot': 'apm_3'}[argv[argv.index('--autopilot') + 1]] or
               ('px4_1' if '14540' in argv[argv.index('--url') + 1] else 'px4_2')] = position
    nodes = evaluate(LAUNCH / launches[0][3])
    procs = []
    with isolated_domain() as (domain, env):
        ctx = rclpy.Context()
        rclpy.init(context=ctx, domain_id=domain)
        observer = rclpy.create_node('walk_through_observer', context=ctx)
        odom = {}
        for name in starts:
            observer.create_subscription(Odometry, f'/{name}/odom', lambda msg, name=name: odom.__setitem__(name, msg),
                                         contract.qos(contract.ODOM))
        executor = rclpy.executors.SingleThreadedExecutor(context=ctx)
        executor.add_node(observer)
        try:
            listening = []
            for i, argv in enumerate(runs):
                procs.append(subprocess.Popen(ros2_run(*argv[2:4], *argv[4:]), cwd=tmp_path, env=env, text=True,
                                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT))
                listening.append(_copy_output(procs[-1], tmp_path / f'vehicle_{i}.log', ' system '))
            for i, event in enumerate(listening):   # as the walk-through says: launch once each emulator listens
                assert event.wait(WAIT_S), (tmp_path / f'vehicle_{i}.log').read_text()
            for node in nodes:
                argv = node.command(tmp_path, Path(get_package_prefix(node.package)))
                with open(tmp_path / f'{node.namespace.strip("/")}_{node.name}.log', 'w') as log:
                    procs.append(subprocess.Popen(argv, cwd=tmp_path, env=env, stdout=log, stderr=subprocess.STDOUT))
            deadline = time.monotonic() + WAIT_S
            while odom.keys() != starts.keys():
                assert time.monotonic() < deadline, (f'odometry from {sorted(odom)} only; bridge logs:\n' + '\n'.join(
                    (tmp_path / f'{n}_mavlink_bridge.log').read_text()[-1500:] for n in starts if n not in odom))
                for proc in procs:
                    assert proc.poll() is None, f'{proc.args} exited with {proc.returncode}'
                executor.spin_once(timeout_sec=0.1)
        finally:
            for proc in procs:
                terminate(proc)
            executor.shutdown()
            observer.destroy_node()
            rclpy.shutdown(context=ctx)
    for name, start in starts.items():
        p = odom[name].pose.pose.position
        assert abs(p.x - start[0]) < 0.1 and abs(p.y - start[1]) < 0.1 and abs(p.z - start[2]) < 0.3, (name, p)


@pytest.mark.parametrize('package, node, config', [('quad_control', 'position_controller', 'control_real.yaml'),
                                                   ('quad_bridge', 'mavlink_bridge', 'bridge_px4.yaml')])
def test_a_node_run_in_a_namespace_refuses_a_params_file_section_rcl_would_skip(tmp_path, package, node, config):
    """`ros2 run PKG NODE --ros-args -r __ns:=/uav2 --params-file .../config/FILE`: rcl gives the file's plain
    `NODE:` section to /NODE only, so the node ran on its defaults (a pd controller with the seed's gains; a bridge
    without its geofence). It refuses to start now, naming the file and the keys that would reach it."""
    from quad_common.paths import resolve_config
    with isolated_domain() as (_, env):
        out = subprocess.run(ros2_run(package, node, '--ros-args', '-r', '__ns:=/uav2', '--params-file',
                                      str(resolve_config(config))),
                             env=env, cwd=tmp_path, capture_output=True, text=True, timeout=WAIT_S)
    text = out.stdout + out.stderr
    assert out.returncode == 2, text
    assert f'its `{node}:` section reaches /{node} only, not /uav2/{node} (rcl): key it `/**/{node}:`' in text
    assert 'Traceback' not in text
