"""The console scripts of quad_bringup's nodes (setup.py): quad_common.node_start records stop signals before the
node's module (rclpy, numpy, ...) is imported, so Ctrl-C during start-up exits 0 quietly."""

from quad_common.node_start import run


def recorder():
    return run('quad_bringup.recording.recorder_node')
