"""The real-vehicle graph shared by launch/px4.launch.py and launch/ardupilot.launch.py: trajectory_node +
position_controller + mavlink_bridge on wall-clock time (use_sim_time false, lockstep false).
Imports `launch`, so only a machine with ROS 2 installed loads it."""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def config(name):
    return os.path.join(get_package_share_directory('quad_bringup'), 'config', name)


def bridge_launch_description(bridge_config: str) -> LaunchDescription:
    def graph(context):
        mission = LaunchConfiguration('mission').perform(context)
        vehicle = LaunchConfiguration('vehicle').perform(context)
        fcu_url = LaunchConfiguration('fcu_url').perform(context)
        wall_time = {'use_sim_time': False}
        return [
            Node(package='quad_trajectory', executable='trajectory_node', name='trajectory_node', output='screen',
                 parameters=[config('trajectory.yaml'), wall_time,
                             {'mission_file': mission, 'vehicle_file': vehicle}]),
            Node(package='quad_control', executable='position_controller', name='position_controller',
                 output='screen',
                 parameters=[config('control.yaml'), wall_time, {'lockstep': False, 'vehicle': vehicle}]),
            Node(package='quad_bridge', executable='mavlink_bridge', name='mavlink_bridge', output='screen',
                 parameters=[config(bridge_config), wall_time, {'fcu_url': fcu_url} if fcu_url else {}]),
        ]

    return LaunchDescription([
        DeclareLaunchArgument('mission', default_value=config('missions/maze.yaml'), description='mission YAML'),
        DeclareLaunchArgument('vehicle', default_value=config('vehicles/px4_quad.yaml'), description='vehicle YAML'),
        DeclareLaunchArgument('fcu_url', default_value='', description='overrides the bridge config fcu_url'),
        OpaqueFunction(function=graph),
    ])
