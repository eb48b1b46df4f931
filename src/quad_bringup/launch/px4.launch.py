"""A mission on a PX4 vehicle through mavlink_bridge (config/bridge_px4.yaml: udpin 14540, PX4 SITL's
offboard port). Arm and enter OFFBOARD with the bridge's services once setpoints stream (docs/bridge.md).

    ros2 launch quad_bringup px4.launch.py mission:=/path/to/mission.yaml
"""

from quad_bringup.bridge_launch import bridge_launch_description


def generate_launch_description():
    return bridge_launch_description('bridge_px4.yaml')
