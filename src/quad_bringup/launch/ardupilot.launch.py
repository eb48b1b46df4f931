"""A mission on a ArduPilot Copter vehicle (quad_bringup.running.graph.bridge_graph): trajectory_node and
position_controller on wall-clock time,
mavlink_bridge from config/bridge_ardupilot.yaml (tcp 5760, ArduPilot SITL's port).
Start in any order: the plan runs only once `offboard` has handed the vehicle over (GUIDED_NOGPS), from where the
vehicle is then (docs/bridge.md, "Flying a real vehicle").

    ros2 launch quad_bringup ardupilot.launch.py mission:=/path/to/mission.yaml [fcu_url:=...] [hover_throttle:=0.42]
    ros2 launch quad_bringup ardupilot.launch.py mission:=... external_pose:=enu   # indoors
"""

from quad_bringup.running.launch_graph import launch_description


def generate_launch_description():
    return launch_description('ardupilot')
