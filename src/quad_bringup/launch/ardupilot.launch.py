"""A mission on an ArduPilot Copter: trajectory_node + position_controller + mavlink_bridge on wall-clock time,
the bridge from config/bridge_ardupilot.yaml (tcp 5760, ArduPilot SITL's port). Arm and enter GUIDED_NOGPS with
the bridge's services once setpoints stream (docs/bridge.md).

    ros2 launch quad_bringup ardupilot.launch.py mission:=/path/to/mission.yaml [fcu_url:=...]
"""

from launch import LaunchDescription
from launch.actions import OpaqueFunction
from launch_ros.actions import Node

from quad_bringup.bridge_launch import arguments, bridge_overrides, config, planning_and_control


def graph(context):
    return planning_and_control(context) + [
        Node(package='quad_bridge', executable='mavlink_bridge', name='mavlink_bridge', output='screen',
             parameters=[config('bridge_ardupilot.yaml'), bridge_overrides(context)]),
    ]


def generate_launch_description():
    return LaunchDescription(arguments() + [OpaqueFunction(function=graph)])
