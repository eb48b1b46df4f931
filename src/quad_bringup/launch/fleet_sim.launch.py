"""A fleet in the simulator (quad_bringup.running.graph.fleet_sim_graph): one sim_node stepping every vehicle of the
fleet file under one /clock (lockstep), and under each vehicle's name as namespace its trajectory_node (its plan of the
fleet) and position_controller (its controller and profile), as `quadflight fly FLEET.yaml` starts them without
its recorder. A fleet whose plans conflict is refused before anything starts.

    ros2 launch quad_bringup fleet_sim.launch.py mission:=/path/to/fleet.yaml
"""

from quad_bringup.running.launch_graph import launch_description


def generate_launch_description():
    return launch_description('fleet_sim')
