"""The floor for bench_bridge: the least a ROS -> MAVLink bridge can do. A single-threaded rclpy node that sends
one SET_ATTITUDE_TARGET (pymavlink, PX4 thrust T = hover f / g) for every cmd/attitude_thrust it takes, and
nothing else (no checks, no hand-over, no telemetry).

    python bench/bridge_echo.py PORT HOVER_THROTTLE   (ROS args: -r __ns:=...)
"""

import os
import sys

os.environ['MAVLINK20'] = '1'
import rclpy  # noqa: E402
from pymavlink import mavutil  # noqa: E402
from rclpy.executors import ExternalShutdownException  # noqa: E402
from sensor_msgs.msg import Imu  # noqa: E402


def main():
    port, hover = int(sys.argv[1]), float(sys.argv[2])
    rclpy.init(args=sys.argv)
    conn = mavutil.mavlink_connection(f'udpout:127.0.0.1:{port}', source_system=1, source_component=191)
    node = rclpy.create_node('bridge_echo')
    mask = 7  # body rates ignored

    def on_setpoint(msg):
        q = msg.orientation
        conn.mav.set_attitude_target_send(0, 1, 1, mask, [q.w, q.x, q.y, q.z], 0.0, 0.0, 0.0,
                                          min(max(hover * msg.linear_acceleration.z / 9.81, 0.0), 1.0))

    node.create_subscription(Imu, 'cmd/attitude_thrust', on_setpoint, 10)
    spin(node)


def spin(node):
    """rclpy's own executor until Ctrl-C or shutdown (also bench/bridge_floor.py's)."""
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
