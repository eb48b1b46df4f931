"""The launch files as `ros2 launch` runs them (launch_standin: launch's and launch_ros' semantics), and their
nodes started as launch_ros starts them: the installed console script, `--ros-args -r __node:=NAME
--params-file ...` in the launch file's order.

- sim.launch.py is the graph `quadflight fly` starts (same nodes, same parameters but fly's lockstep followers),
  and flies a mission to completion;
- px4.launch.py / ardupilot.launch.py pass every documented launch argument to its node; against the emulated
  autopilot, `offboard` called 20 s after launch does not dash: the plan starts from where the vehicle is;
- fleet.launch.py starts each vehicle's three nodes under its namespace with its autopilot, fcu_url and system id,
  and refuses a vehicle without them, shared system ids and a fleet whose plans conflict (test_bridge_fleet.py
  flies it against three emulated vehicles);
- indoors (external_pose, state_source): the bridge forwards the motion capture and the controller flies from it in
  one frame; against the emulator without GPS and its motion-capture stand-in, the walk-through's calls (arm,
  offboard, the plan to its end, land) fly.
"""

import ast
import importlib
import math
import subprocess
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import yaml
from ament_index_python.packages import get_package_prefix
from launch_standin import evaluate
from std_srvs.srv import SetBool

from quad_bringup.emulated.vehicle_graph import (
    VEHICLE_FILE,
    VEHICLE_PARAMS,
    WAIT_S,
    Observer,
    Processes,
    free_udp_port,
)
from quad_bringup.running import flight_options, graph
from quad_common.conversions import stamp_to_s
from quad_common.ros.testing import isolated_domain

ROOT = Path(__file__).resolve().parents[2]
LAUNCH = ROOT / 'src' / 'quad_bringup' / 'launch'
MAZE = ROOT / 'config' / 'missions' / 'maze.yaml'
SPEED_MPS = 0.5
PLAN_PASSED_S = 1.0         # the user calls `offboard` once the plan's clock is this far past its end
SETTLE_S = 2.0              # after engagement: no more than 2 x the mission's speed, within 0.3 m
DASH_SPEED_MPS = 2 * SPEED_MPS
DASH_DISTANCE_M = 0.3


def _mission(tmp_path, waypoints, vehicle=VEHICLE_FILE):
    path = tmp_path / 'short.yaml'
    path.write_text(f'name: short\nvehicle: {vehicle}\nwaypoints: {waypoints}\nyaw: 0.0\n'
                    f'trajectory: {{method: minsnap, speed: {SPEED_MPS}, time_allocation: sqrt}}\n')
    return path


def _console_scripts(package: str) -> set[str]:
    """The `name = module:function` entry points of src/<package>/setup.py."""
    tree = ast.parse((ROOT / 'src' / package / 'setup.py').read_text())
    return {n.value.split('=')[0].strip() for n in ast.walk(tree)
            if isinstance(n, ast.Constant) and isinstance(n.value, str) and ' = ' in n.value and ':' in n.value}


@pytest.mark.parametrize('kind', sorted(graph.LAUNCH_FILES))
def test_launch_file_starts_installed_executables_with_existing_params_files(kind, tmp_path):
    nodes = evaluate(LAUNCH / f'{kind}.launch.py')
    assert nodes, f'{kind}.launch.py starts no node'
    for node in nodes:
        assert node.executable in _console_scripts(node.package), f'{node.package} has no {node.executable}'
        argv = node.command(tmp_path, Path(get_package_prefix(node.package)))
        assert Path(argv[0]).is_file(), f'{argv[0]} is not installed (colcon build)'
        assert argv[1:4] == ['--ros-args', '-r', f'__node:={node.name}']
        if node.namespace:
            assert argv[4:6] == ['-r', f'__ns:={node.namespace}']
            argv = argv[:4] + argv[6:]
        files = argv[5::2]
        assert files and all(Path(f).is_file() for f in files) and argv[4::2] == ['--params-file'] * len(files)


NODE_TABLES = {'position_controller': 'quad_control.parameters', 'mavlink_bridge': 'quad_bridge.parameters',
               'trajectory_node': 'quad_trajectory.trajectory_node', 'sim_node': 'quad_sim.parameters'}


def as_run(spec: graph.NodeSpec) -> dict:
    """What the node runs with: its table's defaults under the parameters the launch hands it (a params file under
    config/ sets only what differs from them)."""
    defaults = {p.name: p.default for p in importlib.import_module(NODE_TABLES[spec.name]).SPECS
                if isinstance(p.default, (bool, int, float, str, list))}
    return {**defaults, **spec.merged_parameters()}


def _merged(nodes, run=False) -> dict:
    """{node: the parameters the launch hands it} (run: over the node's defaults, what it runs with)."""
    merged = {n.name: graph.NodeSpec(n.name, tuple(n.parameters)) for n in nodes}
    return {name: graph.absolute_config_paths(as_run(spec) if run else spec.merged_parameters())
            for name, spec in merged.items()}


def test_sim_launch_starts_the_graph_fly_starts():
    nodes = evaluate(LAUNCH / 'sim.launch.py', mission=str(MAZE), controller='se3')
    assert [(n.package, n.executable, n.name) for n in nodes] == [
        ('quad_trajectory', 'trajectory_node', 'trajectory_node'), ('quad_sim', 'sim_node', 'sim_node'),
        ('quad_control', 'position_controller', 'position_controller')]
    launched = _merged(nodes)
    options = flight_options.with_profile_controller(flight_options.FlightOptions(MAZE, controller='se3'))
    flown = {name: p['ros__parameters'] for name, p in flight_options.node_parameters(options).items()}
    for name, fly_only in graph.FLY_ONLY.items():
        for key in fly_only:
            flown[name].pop(key)
            launched[name].pop(key, None)
    assert launched == flown
    sim, control = launched['sim_node'], launched['position_controller']
    assert sim['world'].endswith('worlds/maze.yaml') and sim['robot_radius_m'] > 0    # collisions are simulated
    se3 = graph.NodeSpec('position_controller', (str(ROOT / 'config' / 'control_se3.yaml'),)).merged_parameters()
    assert all(control[k] == v for k, v in se3.items())                          # the robust profile, not pd's
    assert control['controller'] == 'se3' and sim['mode'] == 'lockstep' and control['lockstep']


def test_sim_launch_realtime_argument():
    nodes = evaluate(LAUNCH / 'sim.launch.py', mode='realtime', rtf='2.5')
    launched = _merged(nodes)
    assert launched['sim_node']['mode'] == 'realtime' and launched['sim_node']['rtf'] == 2.5
    assert not launched['position_controller']['lockstep']
    with pytest.raises(ValueError, match="mode 'fast' refused"):
        evaluate(LAUNCH / 'sim.launch.py', mode='fast')


@pytest.mark.parametrize('autopilot', ['px4', 'ardupilot'])
def test_bridge_launch_arguments_reach_their_nodes(autopilot):
    nodes = evaluate(LAUNCH / f'{autopilot}.launch.py', mission='missions/window.yaml',
                     vehicle='vehicles/crazyflie.yaml', control_profile='control_fast.yaml',
                     fcu_url='udpin:127.0.0.1:14999', hover_throttle='0.42', vehicle_params='adopt')
    assert [n.name for n in nodes] == ['trajectory_node', 'position_controller', 'mavlink_bridge']
    p = _merged(nodes, run=True)
    crazyflie = str(ROOT / 'config' / 'vehicles' / 'crazyflie.yaml')
    assert p['trajectory_node']['vehicle_file'] == crazyflie == p['position_controller']['vehicle']
    assert p['trajectory_node']['mission_file'] == str(ROOT / 'config' / 'missions' / 'window.yaml')
    assert p['position_controller']['controller'] == 'se3'         # control_fast.yaml's
    assert p['position_controller']['wait_for_engagement'] and not p['position_controller']['use_sim_time']
    assert p['mavlink_bridge']['fcu_url'] == 'udpin:127.0.0.1:14999'
    assert p['mavlink_bridge']['hover_throttle'] == 0.42 and p['mavlink_bridge']['vehicle_params'] == 'adopt'
    assert p['mavlink_bridge']['autopilot'] == autopilot
    defaults = _merged(evaluate(LAUNCH / f'{autopilot}.launch.py'), run=True)
    assert defaults['position_controller']['vehicle'].endswith('px4_quad.yaml')
    assert defaults['mavlink_bridge']['hover_throttle'] == 0.5     # the node's default
    with pytest.raises(ValueError, match="hover_throttle 'half' refused"):
        evaluate(LAUNCH / f'{autopilot}.launch.py', hover_throttle='half')


@pytest.mark.parametrize('kind', ['px4', 'ardupilot', 'fleet'])
def test_indoor_launch_arguments_reach_the_bridge_and_the_controller(kind, tmp_path):
    """external_pose:=enu|y_up: the bridge forwards external/pose in that frame and the controller flies from it in
    the same frame (state_source:=external_pose, the default then; state_source:=odom: from the autopilot's
    estimate); a bad value, or the controller on a pose the bridge does not
    forward, is refused naming the argument and the value."""
    def launched(**arguments):
        nodes = evaluate(LAUNCH / f'{kind}.launch.py', **arguments)
        return [(as_run(graph.NodeSpec(n.name, tuple(n.parameters), (n.namespace or '/')[1:])),
                 as_run(graph.NodeSpec(m.name, tuple(m.parameters), (m.namespace or '/')[1:])))
                for n, m in zip(nodes, nodes[1:]) if (n.name, m.name) == ('position_controller', 'mavlink_bridge')]

    pairs = launched()
    assert pairs and all(not b['external_pose_enabled'] and c['state_source'] == 'odom' for c, b in pairs)
    for frame in ('enu', 'y_up'):
        for control, bridge in launched(external_pose=frame, state_source='external_pose'):
            assert bridge['external_pose_enabled'] and bridge['external_pose_frame'] == frame
            assert control['state_source'] == 'external_pose' and control['external_pose_frame'] == frame
    for control, bridge in launched(external_pose='y_up'):         # by default the controller on the pose too
        assert bridge['external_pose_frame'] == 'y_up' and control['state_source'] == 'external_pose'
        assert control['external_pose_frame'] == 'y_up'
    for control, bridge in launched(external_pose='y_up', state_source='odom'):   # on the autopilot's estimate
        assert bridge['external_pose_frame'] == 'y_up' and control['state_source'] == 'odom'
    profile = tmp_path / 'odom_profile.yaml'   # a profile that says odom keeps it
    profile.write_text('position_controller:\n  ros__parameters:\n    state_source: odom\n')
    for control, _ in launched(external_pose='enu', control_profile=str(profile)):
        assert control['state_source'] == 'odom'
    for arguments, message in ((dict(external_pose='ned'), "external_pose 'ned' refused: must be one of off, enu, "
                                                           "y_up"),
                               (dict(state_source='mocap'), "state_source 'mocap' refused"),
                               (dict(state_source='external_pose'), "state_source 'external_pose' refused with "
                                                                    "external_pose 'off'")):
        with pytest.raises(ValueError, match=message):
            evaluate(LAUNCH / f'{kind}.launch.py', **arguments)


def _fleet_file(tmp_path, vehicles, **fleet):
    """A fleet file of px4_quad vehicles on a shared path: vehicles = [(name, {key: value})]."""
    data = {'name': 'fleet', 'vehicle': VEHICLE_FILE, 'robot_radius_m': 0.3, 'waypoints': [[0, 0, 1], [1, 0, 1]],
            'trajectory': {'speed': SPEED_MPS}, **fleet,
            'vehicles': [{'name': name, **keys} for name, keys in vehicles]}
    path = tmp_path / 'fleet.yaml'
    path.write_text(yaml.safe_dump(data))
    return path


def test_fleet_launch_starts_three_nodes_per_vehicle_under_its_namespace(tmp_path):
    nodes = evaluate(LAUNCH / 'fleet.launch.py')           # config/missions/fleets/sitl3.yaml
    assert [(n.namespace, n.name) for n in nodes] == [(f'/{v}', n) for v in ('px4_1', 'px4_2', 'apm_3') for n in
                                                      ('trajectory_node', 'position_controller', 'mavlink_bridge')]
    p = {(n.namespace, n.name): as_run(graph.NodeSpec(n.name, tuple(n.parameters), n.namespace[1:]))
         for n in nodes}
    for ns, autopilot, url, system_id in (('/px4_1', 'px4', 'udpin:0.0.0.0:14540', 1),
                                          ('/px4_2', 'px4', 'udpin:0.0.0.0:14541', 2),
                                          ('/apm_3', 'ardupilot', 'tcp:127.0.0.1:5770', 3)):
        bridge, control, traj = (p[(ns, n)] for n in ('mavlink_bridge', 'position_controller', 'trajectory_node'))
        assert (bridge['autopilot'], bridge['fcu_url'], bridge['target_system'], bridge['source_system']) == (
            autopilot, url, system_id, system_id)
        assert bridge['setpoint_source'] == 'position_controller'     # relative: its namespace's controller
        own = graph.NodeSpec('mavlink_bridge', (str(ROOT / 'config' / f'bridge_{autopilot}.yaml'),)).merged_parameters()
        assert {k: bridge[k] for k in own if k not in ('fcu_url', 'target_system', 'source_system')} == \
            {k: v for k, v in own.items() if k not in ('fcu_url', 'target_system', 'source_system')}
        assert traj['mission_file'] == str(ROOT / 'config' / 'missions' / 'fleets' / 'sitl3.yaml')
        assert traj['fleet_vehicle'] == ns[1:] and not traj['use_sim_time']
        assert traj['vehicle_file'] == control['vehicle'] == str(ROOT / 'config' / 'vehicles' / 'px4_quad.yaml')
        real = graph.NodeSpec('position_controller', (str(ROOT / 'config' / 'control.yaml'),
                                                      str(ROOT / 'config' / 'control_real.yaml'))).merged_parameters()
        assert {k: control[k] for k in real if k != 'vehicle'} == {k: v for k, v in real.items() if k != 'vehicle'}
        assert control['wait_for_engagement'] and not control['lockstep']
    # the launch arguments: a vehicle's own profile and controller win over control_profile
    fleet = _fleet_file(tmp_path, [
        ('a', {'autopilot': 'px4', 'fcu_url': 'udpin:127.0.0.1:14600', 'system_id': 7, 'offset': [0, -1, 0]}),
        ('b', {'autopilot': 'ardupilot', 'fcu_url': 'udpin:127.0.0.1:14601', 'system_id': 8, 'offset': [0, 1, 0],
               'controller': 'pid', 'profile': str(ROOT / 'config' / 'control_real.yaml')})])
    nodes = evaluate(LAUNCH / 'fleet.launch.py', mission=str(fleet), control_profile='control_fast.yaml',
                     hover_throttle='0.42', vehicle_params='adopt')
    p = {(n.namespace, n.name): as_run(graph.NodeSpec(n.name, tuple(n.parameters), n.namespace[1:]))
         for n in nodes}
    assert p[('/a', 'position_controller')]['controller'] == 'se3'           # control_fast.yaml's
    assert p[('/b', 'position_controller')]['controller'] == 'pid'
    for ns in ('/a', '/b'):
        assert p[(ns, 'mavlink_bridge')]['hover_throttle'] == 0.42
        assert p[(ns, 'mavlink_bridge')]['vehicle_params'] == 'adopt'
    assert p[('/b', 'mavlink_bridge')]['target_system'] == 8 and p[('/b', 'mavlink_bridge')]['autopilot'] == 'ardupilot'


def test_fleet_sim_launch_starts_one_simulator_and_each_vehicles_nodes_as_fly_does(tmp_path):
    nodes = evaluate(LAUNCH / 'fleet_sim.launch.py')        # config/missions/fleets/formation4.yaml
    names = ('cf1', 'cf2', 'cf3', 'cf4')
    assert [(n.namespace or '', n.name) for n in nodes] == [('', 'sim_node')] + [
        (f'/{v}', n) for v in names for n in ('trajectory_node', 'position_controller')]
    launched = {(n.namespace or '', n.name): graph.NodeSpec(n.name, tuple(n.parameters),
                                                             (n.namespace or '/')[1:]).merged_parameters()
                for n in nodes}
    flown = {(s.namespace, s.name): s.merged_parameters()
             for s in graph.fleet_sim_graph(ROOT / 'config' / 'missions' / 'fleets' / 'formation4.yaml')}
    assert launched.keys() == {(f'/{ns}' if ns else '', n) for ns, n in flown}
    for (ns, name), values in flown.items():
        assert launched[(f'/{ns}' if ns else '', name)] == values
    sim = launched[('', 'sim_node')]
    assert sim['vehicle_names'] == list(names) and len(sim['initial_positions']) == 12
    assert launched[('/cf4', 'position_controller')]['controller'] == 'pid'
    crossing = str(ROOT / 'config' / 'missions' / 'fleets' / 'crossing2.yaml')
    with pytest.raises(ValueError, match='separation conflict: cf1 and cf2'):
        evaluate(LAUNCH / 'fleet_sim.launch.py', mission=crossing)


@pytest.mark.parametrize('vehicles, fleet, message', [
    ([('a', {'autopilot': 'px4', 'fcu_url': 'udpin:127.0.0.1:14600', 'offset': [0, -1, 0]})], {},
     r"vehicles\[0\] \(a\): system_id is missing: a vehicle flown through a bridge needs autopilot, fcu_url, "
     r"system_id"),
    ([('a', {'system_id': 1, 'fcu_url': 'udpin:127.0.0.1:14600'})], {},
     r"vehicles\[0\] \(a\): autopilot is missing"),
    ([('a', {'autopilot': 'px4', 'system_id': 1, 'fcu_url': 'udpin:127.0.0.1:14600'}),
      ('b', {'autopilot': 'px4', 'system_id': 2, 'fcu_url': 'udpin:127.0.0.1:14601', 'offset': [0, 0.2, 0]})], {},
     r"separation conflict: a and b come 0.200 m apart"),
    ([('a', {'autopilot': 'px4', 'system_id': 1, 'fcu_url': 'udpin:127.0.0.1:14600'}),
      ('b', {'autopilot': 'px4', 'system_id': 1, 'fcu_url': 'udpin:127.0.0.1:14601', 'offset': [0, 1, 0]})], {},
     r"vehicles\[1\] \(b\): system_id = 1 is already vehicles\[0\] \(a\)'s"),
])
def test_fleet_launch_refuses_naming_the_vehicle_and_the_field(tmp_path, vehicles, fleet, message):
    with pytest.raises(ValueError, match=message):
        evaluate(LAUNCH / 'fleet.launch.py', mission=str(_fleet_file(tmp_path, vehicles, **fleet)))


def test_a_namespaced_node_gets_what_merged_parameters_says(tmp_path, ros_env):
    """rcl gives a params file's plain `NAME:` section to /NAME only: under a namespace the node gets '/**',
    '/**/NAME' and '/NS/NAME' of the file itself. A namespaced NodeSpec is therefore started with merged_parameters
    as one '/**' dict (launch_parameters, in ros_arguments and launch_graph): the node gets every section."""
    import json
    import sys
    params = tmp_path / 'p.yaml'
    params.write_text(yaml.safe_dump({name: {'ros__parameters': {key: 1}} for name, key in (
        ('mavlink_bridge', 'a'), ('/cf1/mavlink_bridge', 'b'), ('/**/mavlink_bridge', 'c'), ('/**', 'd'))}))
    probe = ('import json, sys, rclpy; rclpy.init(args=sys.argv); n = rclpy.create_node("x", '
             'allow_undeclared_parameters=True, automatically_declare_parameters_from_overrides=True); '
             'print(json.dumps(sorted(k for k in "abcd" if n.has_parameter(k))))')

    def given(ros_args):
        out = subprocess.run([sys.executable, '-c', probe, *ros_args], env=ros_env, capture_output=True, text=True,
                             timeout=60)
        return json.loads(out.stdout.splitlines()[-1]) if out.stdout.strip() else out.stderr

    raw = ['--ros-args', '-r', '__node:=mavlink_bridge', '-r', '__ns:=/cf1', '--params-file', str(params)]
    assert given(raw) == ['b', 'c', 'd']                         # rcl: the plain `mavlink_bridge:` is skipped
    for namespace, expected in (('cf1', ['a', 'b', 'c', 'd']), ('', ['a', 'c', 'd'])):
        spec = graph.NodeSpec('mavlink_bridge', (str(params),), namespace)
        assert sorted(spec.merged_parameters()) == expected
        assert given(spec.ros_arguments(tmp_path)) == expected


# --- the launched graphs -----------------------------------------------------------------------------------

@contextmanager
def _launched(tmp_path):
    """(start, procs, observer): start(launch_file, **arguments) runs its nodes as launch_ros does, in the root
    namespace of a ROS domain of their own (the config files name the nodes there)."""
    with isolated_domain() as (domain, env):
        procs = Processes(env, tmp_path, namespace='/')
        observer = Observer(domain, '/')

        def start(launch_file, reverse=False, names=None, **arguments):
            """names: only these of its nodes (default all)."""
            nodes = [n for n in evaluate(launch_file, **arguments) if names is None or n.name in names]
            for node in reversed(nodes) if reverse else nodes:
                argv = node.command(tmp_path, Path(get_package_prefix(node.package)))
                log = open(tmp_path / f'{node.name}.log', 'w')
                procs.procs[node.name] = subprocess.Popen(argv, env=procs.env, stdout=log, stderr=subprocess.STDOUT)
        try:
            yield start, procs, observer
        finally:
            procs.stop_all()
            observer.close()


def _node_names(observer):
    return sorted(f'{ns.rstrip("/")}/{name}' for name, ns in observer.node.get_node_names_and_namespaces())


def test_sim_launch_graph_flies_the_mission(tmp_path):
    waypoints = [[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [1.0, 0.5, 1.2]]
    with _launched(tmp_path) as (start, procs, observer):
        start(LAUNCH / 'sim.launch.py', mission=str(_mission(tmp_path, waypoints,
                                                              ROOT / 'config/vehicles/crazyflie.yaml')))
        observer.wait_for(lambda: observer.trajectory is not None, 'the plan')
        traj = observer.trajectory
        end_s = stamp_to_s(traj.header.stamp) + stamp_to_s(traj.points[-1].time_from_start)
        observer.wait_for(lambda: observer.odom and observer.odom[-1][0] > end_s + 1.0, 'the end of the mission')
        assert np.linalg.norm(np.array(observer.position()) - waypoints[-1]) < 0.05
        names = _node_names(observer)
        for name in ('/trajectory_node', '/sim_node', '/position_controller'):
            assert names.count(name) == 1, names
        for name in procs.procs:
            assert procs.procs[name].poll() is None, procs.log(name)


CONTROLLER_LATE_S = 3.0   # sim seconds past the plan's start before the controller is started
FUTURE_ODOM_BOUND = 20    # odometry refused as ahead of the controller's clock (odom before /clock: ~175 at rtf 2)


@pytest.mark.parametrize('rtf', [1.0, 2.0])
def test_sim_launch_realtime_flies_the_mission_with_a_late_controller(tmp_path, rtf):
    """mode:=realtime with position_controller started only once sim time is CONTROLLER_LATE_S past the plan's
    start: the simulator holds the vehicle where it starts until the first setpoint (it used to sink and land by
    the failsafe, and the plan was refused for good: 'begins 0.856 m from the vehicle'), and the plan begins
    where the vehicle is at engagement, then flies to its end."""
    waypoints = [[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [1.0, 0.5, 1.2]]
    mission = str(_mission(tmp_path, waypoints, ROOT / 'config/vehicles/crazyflie.yaml'))
    launch = LAUNCH / 'sim.launch.py'
    with _launched(tmp_path) as (start, procs, observer):
        start(launch, names={'trajectory_node', 'sim_node'}, mission=mission, mode='realtime', rtf=str(rtf))
        observer.wait_for(lambda: observer.trajectory is not None, 'the plan')
        plan_start_s = stamp_to_s(observer.trajectory.header.stamp)
        observer.wait_for(lambda: observer.odom and observer.odom[-1][0] > plan_start_s + CONTROLLER_LATE_S,
                          'sim time past the plan\'s start')
        with observer.lock:
            waiting = np.array([p for _, p in observer.odom])
        assert np.abs(waiting - waypoints[0]).max() < 1e-6, 'the vehicle moved before any setpoint'
        start(launch, names={'position_controller'}, mission=mission, mode='realtime', rtf=str(rtf))
        observer.wait_for(lambda: observer.controller()[1].get('mode') == 'hold (trajectory ended)',
                          'the end of the plan', WAIT_S + 60.0)
        _, values = observer.controller()
        print(f'rtf {rtf}: odometry refused as ahead of the controller\'s clock: {values["future_odom"]}')
        assert values['refused_start_steps'] == '0', values
        assert int(values['future_odom']) < FUTURE_ODOM_BOUND, values
        observer.wait_for(lambda: np.linalg.norm(np.array(observer.position()) - waypoints[-1]) < 0.05,
                          'the vehicle at the last waypoint')
        for name in procs.procs:
            assert procs.procs[name].poll() is None, procs.log(name)


@pytest.mark.parametrize('autopilot,reverse', [('px4', False), ('ardupilot', False), ('px4', True)],
                         ids=['px4', 'ardupilot', 'px4-reverse-order'])
def test_bridge_launch_graph_does_not_dash_when_offboard_comes_late(tmp_path, autopilot, reverse):
    """The plan used to run on the wall clock from launch: `offboard` 20 s later flew the vehicle to
    where the plan had got to (a 7 m dash at 5.9 m/s). Now it begins where the vehicle is when handed over,
    whatever order the nodes started in (launch's, or the bridge first and trajectory_node last). `offboard`
    comes once the clock is past the plan's end (a plan on the wall clock would be at its last waypoint, 1.8 m
    away), not after a fixed delay."""
    waypoints = [[0.0, 0.0, 1.0], [1.5, 0.0, 1.0], [1.5, 1.0, 1.2]]
    port = free_udp_port()
    with _launched(tmp_path) as (start, procs, observer):
        procs.vehicle(autopilot, f'udpout:127.0.0.1:{port}', position=waypoints[0],
                      extra=VEHICLE_PARAMS[autopilot])
        start(LAUNCH / f'{autopilot}.launch.py', reverse, mission=str(_mission(tmp_path, waypoints)),
              fcu_url=f'udpin:127.0.0.1:{port}')
        observer.wait_for(lambda: observer.trajectory is not None, 'the plan')
        observer.wait_for(lambda: observer.link()[1].get('armed') == 'True', 'the bridge to see the armed vehicle')
        assert _node_names(observer).count('/mavlink_bridge') == 1, _node_names(observer)
        assert '/mavlink_bridge_setpoints' in _node_names(observer)
        plan = observer.trajectory
        plan_end_s = stamp_to_s(plan.header.stamp) + stamp_to_s(plan.points[-1].time_from_start)
        observer.wait_for(lambda: observer.odom and observer.odom[-1][0] > plan_end_s + PLAN_PASSED_S,
                          'the clock past the plan\'s end')
        assert observer.controller()[1].get('engaged') == 'False'
        with observer.lock:
            n_before = len(observer.odom)
        result = observer.call('offboard', SetBool.Request(data=True))
        assert result.success, result.message
        engaged_at = observer.odom[-1][0]
        observer.wait_for(lambda: observer.odom[-1][0] > engaged_at + SETTLE_S, 'two seconds after engagement')
        with observer.lock:
            odom = [(t, p) for t, p in observer.odom[n_before:]]
        t = np.array([s for s, _ in odom])
        p = np.array([q for _, q in odom])
        first = t <= engaged_at + SETTLE_S
        at_engagement = p[np.searchsorted(t, engaged_at)]
        dist = np.linalg.norm(p[first] - at_engagement, axis=1).max()
        window = (t[1:] - t[:-1]) > 0
        speed = np.linalg.norm(np.diff(p, axis=0), axis=1)[window] / np.diff(t)[window]
        peak = np.convolve(speed, np.ones(5) / 5, mode='valid')[: max(1, int(first.sum()) - 5)].max()  # 0.1 s
        print(f'{autopilot}: offboard {engaged_at - plan_end_s:.1f} s after the plan\'s end: first {SETTLE_S} s '
              f'moved {dist:.3f} m, peak {peak:.2f} m/s')
        assert dist < DASH_DISTANCE_M and peak < DASH_SPEED_MPS
        _, values = observer.controller()
        assert values['engaged'] == 'True' and values['refused_start_steps'] == '0'
        # ... then flies the mission to its end
        traj_s = stamp_to_s(observer.trajectory.points[-1].time_from_start)
        observer.wait_for(lambda: observer.odom[-1][0] > engaged_at + 1.0 + traj_s + 2.0, 'the end of the mission',
                          WAIT_S + traj_s)
        assert np.linalg.norm(np.array(observer.position()) - waypoints[-1]) < 0.15
        assert math.isfinite(peak)


def test_launch_refuses_an_unknown_controller_before_any_node_starts():
    with pytest.raises(ValueError, match="controller = 'foo' refused: must be one of pd, pid, se3"):
        evaluate(LAUNCH / 'sim.launch.py', controller='foo')


@pytest.mark.parametrize('kind', sorted(graph.LAUNCH_FILES))
def test_every_launched_node_ends_the_launch_when_it_exits(kind):
    """on_exit=Shutdown(): a node that refuses its parameters or its plan (exit 2) ends `ros2 launch` instead of
    leaving the rest of the graph running without it; but in a fleet of real vehicles one vehicle's node exit
    leaves the others flying (its bridge lands its vehicle alone: test_bridge_fleet)."""
    from launch_standin import Shutdown
    nodes = evaluate(LAUNCH / f'{kind}.launch.py')
    if kind in graph.FAILSAFE_PER_VEHICLE:
        assert all(n.on_exit is None for n in nodes), [(n.name, n.on_exit) for n in nodes]
    else:
        assert all(isinstance(n.on_exit, Shutdown) for n in nodes), [(n.name, n.on_exit) for n in nodes]


def test_a_refused_plan_ends_its_node_with_exit_2(tmp_path, ros_env):
    """What on_exit acts on: trajectory_node started as sim.launch.py starts it, with a plan it refuses."""
    mission = tmp_path / 'refused.yaml'
    mission.write_text('name: refused\nwaypoints: [[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]]\n')
    node = next(n for n in evaluate(LAUNCH / 'sim.launch.py', mission=str(mission)) if n.name == 'trajectory_node')
    out = subprocess.run(node.command(tmp_path, Path(get_package_prefix(node.package))), env=ros_env,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 2, out.stdout + out.stderr
    assert 'needs at least two distinct waypoints' in out.stdout + out.stderr


# --- indoor flight: docs/bridge.md "Indoor flight: motion capture", from ros2 launch ------------------------------

INDOOR_WAYPOINTS = [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [1.0, 1.0, 1.0]]   # from the floor up
INDOOR_END_M = 0.15          # the plan's last waypoint, reached within this (the real-vehicle profile: docs)
EXTERNAL_POSE_STATUS = 'mavlink_bridge: external pose'


@pytest.mark.parametrize('autopilot, state_source', [('px4', ''), ('ardupilot', 'odom')],
                         ids=['px4-external_pose-by-default', 'ardupilot-odom'])
def test_indoor_walk_through_from_ros2_launch_against_the_emulator_and_its_motion_capture(tmp_path, autopilot,
                                                                                          state_source):
    """The emulated autopilot with its GPS off and external vision on (test_bridge_external_pose's EV_PARAMS), its
    motion-capture stand-in (`mavlink_vehicle --mocap-topic external/pose`: the truth, 100 Hz, 1 mm, 10 ms late)
    and <autopilot>.launch.py with external_pose:=enu (the controller flies from the same pose, as the walk-through
    leaves it; state_source:=odom: from the autopilot's estimate). The walk-through's calls in order: arm (the
    autopilot has a position only from the forwarded pose), offboard on the floor (the emulator has no takeoff
    command: the plan's first leg is the takeoff), the plan flown to its end, land, disarmed."""
    from bridge.test_bridge_external_pose import EV_PARAMS
    from launched_params import ParameterReader
    from std_srvs.srv import Trigger

    port = free_udp_port()
    with _launched(tmp_path) as (start, procs, observer):
        ev = [a for value in EV_PARAMS[autopilot] for a in ('--param', value)]
        procs.vehicle(autopilot, f'udpout:127.0.0.1:{port}', position=INDOOR_WAYPOINTS[0],
                      extra=(*VEHICLE_PARAMS[autopilot], *ev, '--mocap-topic', 'external/pose'))
        start(LAUNCH / f'{autopilot}.launch.py', mission=str(_mission(tmp_path, INDOOR_WAYPOINTS)),
              fcu_url=f'udpin:127.0.0.1:{port}', external_pose='enu',
              **({'state_source': state_source} if state_source else {}))
        observer.wait_for(lambda: observer.trajectory is not None, 'the plan')
        observer.wait_for(lambda: observer.status(EXTERNAL_POSE_STATUS)[0] == 'forwarding',
                          f'the bridge forwarding the motion capture ({observer.status(EXTERNAL_POSE_STATUS)})')
        reader = ParameterReader(observer.context.get_domain_id())
        try:
            control = reader.parameters('/position_controller')
        finally:
            reader.close()
        assert (control['state_source'], control['external_pose_frame']) == (state_source or 'external_pose', 'enu')
        observer.wait_for(lambda: observer.call('arm', SetBool.Request(data=True)).success, 'arming accepted')
        observer.wait_for(lambda: observer.link()[1].get('armed') == 'True', 'the bridge to see the armed vehicle')
        result = observer.call('offboard', SetBool.Request(data=True))
        assert result.success, result.message
        observer.wait_for(lambda: observer.controller()[1].get('mode') == 'hold (trajectory ended)',
                          f'the end of the plan ({observer.controller()})', WAIT_S + 60.0)
        end = np.array(INDOOR_WAYPOINTS[-1])
        observer.wait_for(lambda: np.linalg.norm(np.array(observer.position()) - end) < INDOOR_END_M,
                          f'the vehicle within {INDOOR_END_M} m of the last waypoint ({observer.position()})')
        _, values = observer.controller()
        assert values['refused_start_steps'] == '0' and values['engaged'] == 'True', values
        assert observer.status(EXTERNAL_POSE_STATUS)[0] == 'forwarding'   # no pose fault ended the flight
        with observer.lock:
            heights = [p[2] for _, p in observer.odom]
        miss_m = np.linalg.norm(np.array(observer.position()) - end)
        print(f'indoor, {autopilot}, state_source {state_source or "external_pose"}: {miss_m:.3f} m from the last '
              f'waypoint, highest '
              f'{max(heights):.2f} m, pose age '
              f'{observer.status(EXTERNAL_POSE_STATUS)[1].get("age_ms")} ms')
        result = observer.call('land', Trigger.Request())
        assert result.success, result.message
        observer.wait_for(lambda: observer.link()[1].get('armed') == 'False', 'the vehicle landed and disarmed')
        assert observer.position()[2] < 0.1
        for name in procs.procs:
            assert procs.procs[name].poll() is None, procs.log(name)
