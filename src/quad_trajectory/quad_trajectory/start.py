"""The console scripts of quad_trajectory's nodes (setup.py): quad_common.node_start records stop signals before the
node's module (rclpy, numpy, ...) is imported, so Ctrl-C during start-up exits 0 quietly."""

from quad_common.node_start import run


def trajectory_node():
    return run('quad_trajectory.trajectory_node')
