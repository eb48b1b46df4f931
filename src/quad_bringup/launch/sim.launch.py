"""The simulated flight graph (the one `quadflight fly` starts): trajectory_node, position_controller and
sim_node in lockstep on simulated time, parameters from config/ (installed to share/quad_bringup/config).

    ros2 launch quad_bringup sim.launch.py mission:=/path/to/mission.yaml controller:=pid
"""

import os

import yaml
from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def config(name):
    return os.path.join(get_package_share_directory('quad_bringup'), 'config', name)


def graph(context):
    mission = LaunchConfiguration('mission').perform(context)
    controller = LaunchConfiguration('controller').perform(context)
    with open(mission) as f:
        first_waypoint = [float(v) for v in yaml.safe_load(f)['waypoints'][0]]
    sim_time = {'use_sim_time': True}
    return [
        Node(package='quad_trajectory', executable='trajectory_node', name='trajectory_node', output='screen',
             parameters=[config('trajectory.yaml'), sim_time, {'mission_file': mission}]),
        Node(package='quad_control', executable='position_controller', name='position_controller', output='screen',
             parameters=[config('control.yaml'), sim_time,
                         {'controller': controller, 'lockstep': True, 'wait_for_trajectory': True}]),
        Node(package='quad_sim', executable='sim_node', name='sim_node', output='screen',
             parameters=[config('sim.yaml'), sim_time, {'mode': 'lockstep', 'initial_position': first_waypoint}]),
    ]


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument('mission', default_value=config('missions/maze.yaml'), description='mission YAML'),
        DeclareLaunchArgument('controller', default_value='pd', description='pd | pid | se3'),
        OpaqueFunction(function=graph),
    ])
