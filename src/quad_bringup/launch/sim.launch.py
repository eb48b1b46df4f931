"""The simulated flight graph, the one `quadflight fly` starts (quad_bringup.running.graph.sim_graph): trajectory_node,
sim_node and position_controller on simulated time, lockstep (or realtime at rtf), the mission's world and robot
radius in the simulator, the controller's profile (se3: control_se3.yaml).

    ros2 launch quad_bringup sim.launch.py mission:=missions/window.yaml controller:=se3 [mode:=realtime rtf:=1.0]
"""

from quad_bringup.running.launch_graph import launch_description


def generate_launch_description():
    return launch_description('sim')
