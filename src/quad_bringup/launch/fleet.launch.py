"""A fleet of real vehicles (quad_bringup.running.graph.fleet_bridge_graph): per vehicle of the fleet file, under its
name as namespace, trajectory_node (its plan of the fleet), position_controller and mavlink_bridge (its autopilot's
config/bridge_<autopilot>.yaml with its fcu_url, and its system_id as target_system and source_system). A fleet
whose plans conflict is refused before anything starts. Hand each vehicle over with its own `offboard`
(/NAME/offboard); one vehicle's failsafe (its bridge lands it) commands only that vehicle (docs/bridge.md,
"Fleets of real vehicles").

    ros2 launch quad_bringup fleet.launch.py mission:=/path/to/fleet.yaml [control_profile:=...] [hover_throttle:=0.42]
"""

from quad_bringup.running.launch_graph import launch_description


def generate_launch_description():
    return launch_description('fleet')
