"""A mission on a PX4 vehicle (quad_bringup.running.graph.bridge_graph): trajectory_node and
position_controller on wall-clock time,
mavlink_bridge from config/bridge_px4.yaml (udpin 14540, PX4 SITL's offboard port).
Start in any order: the plan runs only once `offboard` has handed the vehicle over (OFFBOARD), from where the
vehicle is then (docs/bridge.md, "Flying a real vehicle").

    ros2 launch quad_bringup px4.launch.py mission:=/path/to/mission.yaml [fcu_url:=...] [hover_throttle:=0.42]
    ros2 launch quad_bringup px4.launch.py mission:=... external_pose:=enu   # indoors
"""

from quad_bringup.running.launch_graph import launch_description


def generate_launch_description():
    return launch_description('px4')
