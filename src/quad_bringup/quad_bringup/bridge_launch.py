"""What launch/px4.launch.py and launch/ardupilot.launch.py share: the launch arguments and the planning and
control half of the graph (trajectory_node + position_controller on wall-clock time, lockstep false).
Each launch file adds its own mavlink_bridge Node. Imports `launch`: only a machine with ROS 2 loads it."""

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

WALL_TIME = {'use_sim_time': False}


def config(name):
    return os.path.join(get_package_share_directory('quad_bringup'), 'config', name)


def arguments():
    return [
        DeclareLaunchArgument('mission', default_value=config('missions/maze.yaml'), description='mission YAML'),
        DeclareLaunchArgument('vehicle', default_value=config('vehicles/px4_quad.yaml'), description='vehicle YAML'),
        DeclareLaunchArgument('control_profile', default_value=config('control_real.yaml'),
                              description='position_controller profile over control.yaml (real-vehicle profile)'),
        DeclareLaunchArgument('fcu_url', default_value='', description='overrides the bridge config fcu_url'),
    ]


def bridge_overrides(context) -> dict:
    fcu_url = LaunchConfiguration('fcu_url').perform(context)
    return dict(WALL_TIME, **({'fcu_url': fcu_url} if fcu_url else {}))


def planning_and_control(context):
    mission = LaunchConfiguration('mission').perform(context)
    vehicle = LaunchConfiguration('vehicle').perform(context)
    profile = LaunchConfiguration('control_profile').perform(context)
    return [
        Node(package='quad_trajectory', executable='trajectory_node', name='trajectory_node', output='screen',
             parameters=[config('trajectory.yaml'), WALL_TIME, {'mission_file': mission, 'vehicle_file': vehicle}]),
        Node(package='quad_control', executable='position_controller', name='position_controller', output='screen',
             parameters=[config('control.yaml'), profile, WALL_TIME, {'lockstep': False, 'vehicle': vehicle}]),
    ]
