"""Each launch file included under a pushed namespace (GroupAction([PushRosNamespace('uav2'),
IncludeLaunchDescription(...)]), the standard way to run a second vehicle) and with its `namespace` argument gives
every node exactly the parameters it has at the root: read back from the running nodes through their parameter
services, as `ros2 param dump` reads them. rcl gives a params file's plain `NAME:` section to /NAME only, so a
launch that handed the files on as they are flew /uav2's nodes on their built-in defaults."""

from pathlib import Path

import pytest
import yaml
from launched_params import PUSHED, launched_parameters, pushed_launch_file

from quad_bringup.emulated.vehicle_graph import free_udp_port
from quad_bringup.running import graph

ROOT = Path(__file__).resolve().parents[2]
LAUNCH = ROOT / 'src' / 'quad_bringup' / 'launch'


def _arguments(kind, tmp_path) -> dict:
    """Launch arguments that keep the graph off the fixed ports the shipped configs name (other tests' vehicles)."""
    if kind == 'sim':    # control_se3.yaml's gains (control.yaml's are the node's own defaults)
        return {'controller': 'se3'}
    if kind in ('px4', 'ardupilot'):
        return {'fcu_url': f'udpin:127.0.0.1:{free_udp_port()}'}
    if kind == 'fleet':
        shipped = ROOT / 'config' / 'missions' / 'fleets' / 'sitl3.yaml'
        fleet = yaml.safe_load(shipped.read_text())
        for v in [fleet, *fleet['vehicles']]:
            if 'vehicle' in v:
                v['vehicle'] = str((shipped.parent / v['vehicle']).resolve())
        for v in fleet['vehicles']:
            v['fcu_url'] = f'udpin:127.0.0.1:{free_udp_port()}'
        path = tmp_path / 'sitl3_free_ports.yaml'
        path.write_text(yaml.safe_dump(fleet))
        return {'mission': str(path)}
    return {}


def _under(namespace: str, params: dict) -> dict:
    return {f'/{namespace}{fqn}': values for fqn, values in params.items()}


@pytest.mark.parametrize('kind', sorted(graph.LAUNCH_FILES))
def test_launch_file_under_a_pushed_namespace_gives_every_node_its_root_parameters(kind, tmp_path):
    arguments = _arguments(kind, tmp_path)
    root = launched_parameters(tmp_path, LAUNCH / f'{kind}.launch.py', **arguments)
    pushed = launched_parameters(tmp_path, pushed_launch_file(tmp_path, LAUNCH / f'{kind}.launch.py', **arguments))
    assert pushed.keys() == _under(PUSHED, root).keys()
    for fqn, values in _under(PUSHED, root).items():
        differing = {k: (v, pushed[fqn].get(k)) for k, v in values.items() if pushed[fqn].get(k) != v}
        assert not differing, f'{fqn}: (root, under /{PUSHED}): {differing}'
        assert pushed[fqn] == values
    if kind == 'sim':
        assert pushed[f'/{PUSHED}/position_controller']['kp_x'] == 25.0                # control_se3.yaml's
    if kind in ('px4', 'ardupilot'):    # the file's values, not the node's defaults (geofence_enabled: False)
        bridge = pushed[f'/{PUSHED}/mavlink_bridge']
        assert bridge['geofence_enabled'] is True and bridge['autopilot'] == kind
        assert pushed[f'/{PUSHED}/position_controller']['controller'] == 'pid'       # control_real.yaml's


def test_namespace_argument_places_the_graph_with_its_parameters(tmp_path):
    arguments = {'namespace': 'team/uav3', **_arguments('px4', tmp_path)}
    root = launched_parameters(tmp_path, LAUNCH / 'px4.launch.py', fcu_url=arguments['fcu_url'])
    placed = launched_parameters(tmp_path, LAUNCH / 'px4.launch.py', **arguments)
    assert placed == _under('team/uav3', root)
    # relative to a pushed namespace, as a launch_ros Node's own namespace is
    pushed = launched_parameters(tmp_path, pushed_launch_file(tmp_path, LAUNCH / 'px4.launch.py', **arguments))
    assert pushed == _under(f'{PUSHED}/team/uav3', root)


def test_namespace_argument_refuses_what_is_no_ros_name(tmp_path):
    from launch_standin import evaluate
    with pytest.raises(ValueError, match=r"namespace 'uav-2' refused: 'uav-2' is no ROS name component"):
        evaluate(LAUNCH / 'sim.launch.py', namespace='uav-2')


def test_every_parameter_answers_a_get_parameters_call_also_the_unset_arrays(tmp_path):
    """`ros2 param dump /trajectory_node` and `/sim_node` printed {}: rclpy answers no get_parameters request that
    names a declared parameter without a value (waypoints; vehicle_names, vehicle_files, initial_positions,
    robot_radii_m). They are empty arrays of their type now, and still take a value of that type."""
    from launched_params import launched
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    with launched(tmp_path, LAUNCH / 'sim.launch.py') as (nodes, reader, alive):
        trajectory = reader.parameters('/trajectory_node', alive('/trajectory_node'))
        sim = reader.parameters('/sim_node', alive('/sim_node'))
        assert trajectory['waypoints'] == []
        assert {k: sim[k] for k in ('vehicle_names', 'vehicle_files', 'initial_positions', 'robot_radii_m')} == \
            dict.fromkeys(('vehicle_names', 'vehicle_files', 'initial_positions', 'robot_radii_m'), [])
        setter = reader.node.create_client(SetParameters, '/trajectory_node/set_parameters')
        request = SetParameters.Request(parameters=[Parameter('waypoints', Parameter.Type.DOUBLE_ARRAY,
                                                              [0.0, 0.0, 1.0, 1.0, 0.0, 1.0]).to_parameter_msg()])
        result = reader._call(setter, request, 'set_parameters', alive('/trajectory_node')).results[0]
        assert result.successful, result.reason
        assert reader.parameters('/trajectory_node', alive('/trajectory_node'))['waypoints'] == [0.0, 0.0, 1.0, 1.0,
                                                                                                   0.0, 1.0]
