"""A mission on an ArduPilot Copter through mavlink_bridge (config/bridge_ardupilot.yaml: tcp 5760, ArduPilot
SITL's port). Arm and enter GUIDED_NOGPS with the bridge's services once setpoints stream (docs/bridge.md).

    ros2 launch quad_bringup ardupilot.launch.py mission:=/path/to/mission.yaml
"""

from quad_bringup.bridge_launch import bridge_launch_description


def generate_launch_description():
    return bridge_launch_description('bridge_ardupilot.yaml')
