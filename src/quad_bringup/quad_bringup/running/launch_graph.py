"""The launch files' one body: the launch arguments of quad_bringup.running.graph and an OpaqueFunction that turns the
graph's NodeSpecs into launch_ros Nodes. Imports `launch`: only a machine with ROS 2 and launch loads it."""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction, Shutdown
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from quad_bringup.running import graph


def launch_node(spec: graph.NodeSpec, pushed_namespace: str = '', ends_launch: bool = True) -> Node:
    """A launch_ros Node of spec under pushed_namespace (the `namespace` argument, under an including file's
    PushRosNamespace). Its parameters are the ones its fully qualified name gets (NodeSpec.launch_parameters: under
    a namespace one dict, since rcl gives a file's plain `NAME:` section to /NAME only); ends_launch: its exit ends
    the launch (a node that refuses its parameters or its plan leaves no half graph flying)."""
    placed = graph.NodeSpec(spec.name, spec.parameters, graph.join_namespace(pushed_namespace, spec.namespace))
    on_exit = Shutdown(reason=f'{placed.fqn} exited: the graph cannot fly without it') if ends_launch else None
    return Node(package=spec.package, executable=spec.executable, name=spec.name,
                namespace='/' + placed.namespace, output='screen', parameters=placed.launch_parameters(),
                on_exit=on_exit)


def launch_description(kind: str) -> LaunchDescription:
    """launch/<kind>.launch.py: kind sim | px4 | ardupilot | fleet | fleet_sim
    (quad_bringup.running.graph.LAUNCH_FILES)."""
    arguments = graph.LAUNCH_FILES[kind] + (graph.NAMESPACE_ARGUMENT,)

    def nodes(context):
        values = {name: LaunchConfiguration(name).perform(context) for name, _, _ in arguments}
        pushed = graph.join_namespace(context.launch_configurations.get('ros_namespace') or '', values['namespace'])
        ends_launch = kind not in graph.FAILSAFE_PER_VEHICLE   # a real fleet: one vehicle's exit lands it alone
        return [launch_node(spec, pushed, ends_launch) for spec in graph.graph_from_arguments(kind, values)]

    return LaunchDescription([DeclareLaunchArgument(name, default_value=default, description=text)
                              for name, default, text in arguments] + [OpaqueFunction(function=nodes)])
