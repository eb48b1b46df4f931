"""A mission on a PX4 vehicle: trajectory_node + position_controller + mavlink_bridge on wall-clock time,
the bridge from config/bridge_px4.yaml (udpin 14540, PX4 SITL's offboard port). Arm and enter OFFBOARD with the
bridge's services once setpoints stream (docs/bridge.md).

    ros2 launch quad_bringup px4.launch.py mission:=/path/to/mission.yaml [fcu_url:=...]
"""

from launch import LaunchDescription
from launch.actions import OpaqueFunction
from launch_ros.actions import Node

from quad_bringup.bridge_launch import arguments, bridge_overrides, config, planning_and_control


def graph(context):
    return planning_and_control(context) + [
        Node(package='quad_bridge', executable='mavlink_bridge', name='mavlink_bridge', output='screen',
             parameters=[config('bridge_px4.yaml'), bridge_overrides(context)]),
    ]


def generate_launch_description():
    return LaunchDescription(arguments() + [OpaqueFunction(function=graph)])
