"""The launch files' one body: the launch arguments of quad_bringup.graph and an OpaqueFunction that turns the
graph's NodeSpecs into launch_ros Nodes. Imports `launch`: only a machine with ROS 2 and launch loads it."""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from quad_bringup import graph


def launch_node(spec: graph.NodeSpec) -> Node:
    return Node(package=spec.package, executable=spec.executable, name=spec.name, namespace=spec.namespace or None,
                output='screen', parameters=spec.launch_parameters())


def launch_description(kind: str) -> LaunchDescription:
    """launch/<kind>.launch.py: kind sim | px4 | ardupilot | fleet (quad_bringup.graph.LAUNCH_FILES)."""
    arguments = graph.LAUNCH_FILES[kind]

    def nodes(context):
        values = {name: LaunchConfiguration(name).perform(context) for name, _, _ in arguments}
        return [launch_node(spec) for spec in graph.graph_from_arguments(kind, values)]

    return LaunchDescription([DeclareLaunchArgument(name, default_value=default, description=text)
                              for name, default, text in arguments] + [OpaqueFunction(function=nodes)])
