"""mavlink_bridge as `python -m quad_bridge.mavlink_bridge_node` runs it, except that its `odom` writer keeps all
its history (KEEP_ALL; reliability and durability as the contract says). Fast DDS bounds such a history by the
writer's resource limits, and a write into a full one waits for the readers' acknowledgements up to the
reliability's max_blocking_time, then fails: with a profile that sets both for the topic
(FASTRTPS_DEFAULT_PROFILES_FILE, a data_writer profile named after the fully qualified topic), a reliable reader
that stops acknowledging makes the bridge's odometry writes block. Run:
python test/blocking_odom_bridge.py --ros-args -p fcu_url:=... -r __ns:=/NAMESPACE"""

from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile

_create_publisher = Node.create_publisher


def _keep_all_odom(self, msg_type, topic, qos, **kwargs):
    if topic == 'odom':
        qos = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=qos.reliability, durability=qos.durability)
    return _create_publisher(self, msg_type, topic, qos, **kwargs)


Node.create_publisher = _keep_all_odom

if __name__ == '__main__':
    from quad_bridge import mavlink_bridge_node
    mavlink_bridge_node.main()
