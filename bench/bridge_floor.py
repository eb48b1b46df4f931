"""The floor for bench_bridge_telemetry: the least a ROS <-> MAVLink bridge with an autopilot's telemetry can do
in Python on rclpy. bench/bridge_echo.py's setpoint echo (one SET_ATTITUDE_TARGET through pymavlink for every
cmd/attitude_thrust taken), plus a receive thread that reads every datagram the vehicle sends and publishes a
serialized `odom` for each LOCAL_POSITION_NED and a serialized `imu` for each HIGHRES_IMU / SCALED_IMU, with the
contract's QoS. Nothing else: no CRC, no decoding (the message id from the frame header, the bytes published
were serialized once at start), no clock, no checks, no hand-over, no link state, no diagnostics.

    python bench/bridge_floor.py PORT HOVER_THROTTLE   (ROS args: -r __ns:=...)
"""

import os
import struct
import sys
import threading

os.environ['MAVLINK20'] = '1'
import rclpy  # noqa: E402
from bridge_echo import spin  # noqa: E402  (bench/, this script's folder)
from nav_msgs.msg import Odometry  # noqa: E402
from pymavlink import mavutil  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402
from sensor_msgs.msg import Imu  # noqa: E402

from quad_common import contract  # noqa: E402

MAVLINK2_MAGIC = 0xFD
LOCAL_POSITION_NED, HIGHRES_IMU, SCALED_IMU = 32, 105, 26


def main():
    port, hover = int(sys.argv[1]), float(sys.argv[2])
    rclpy.init(args=sys.argv)
    conn = mavutil.mavlink_connection(f'udpout:127.0.0.1:{port}', source_system=1, source_component=191)
    conn.port.setblocking(True)
    node = rclpy.create_node('bridge_floor')
    odom_pub = node.create_publisher(Odometry, contract.ODOM, contract.qos(contract.ODOM))
    imu_pub = node.create_publisher(Imu, contract.IMU, contract.qos(contract.IMU))
    odom, imu = serialize_message(Odometry()), serialize_message(Imu())
    send_lock = threading.Lock()

    def receive():
        while True:
            try:
                data = conn.port.recv(65535)
            except OSError:
                return
            if len(data) < 10 or data[0] != MAVLINK2_MAGIC:
                continue
            msg_id = data[7] | data[8] << 8 | data[9] << 16
            if msg_id == LOCAL_POSITION_NED:
                odom_pub.publish(odom)
            elif msg_id in (HIGHRES_IMU, SCALED_IMU):
                imu_pub.publish(imu)

    def on_setpoint(raw):
        # linear_acceleration.z: the 10th double from the end (linear_acceleration_covariance's 9 follow it)
        f_z = struct.unpack_from('<d', raw, len(raw) - 80)[0]
        with send_lock:
            conn.mav.set_attitude_target_send(0, 1, 1, 7, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0,
                                              min(max(hover * f_z / 9.81, 0.0), 1.0))

    node.create_subscription(Imu, contract.SETPOINT, on_setpoint, 10, raw=True)
    threading.Thread(target=receive, daemon=True).start()
    spin(node)


if __name__ == '__main__':
    main()
