"""`odom` seen from a process of its own: one line per message, `ARRIVAL_NS STAMP_NS` (arrival on
CLOCK_MONOTONIC, which every process on the machine shares), so a test can measure odometry gaps that its own
busy interpreter cannot distort. Run: python test/odom_probe.py --ros-args -r __ns:=/NAMESPACE"""

import time

from nav_msgs.msg import Odometry
from rclpy.node import Node

from quad_common import contract
from quad_common.ros import cdr
from quad_common.ros.node_main import run_node


class OdomProbe(Node):
    def __init__(self):
        super().__init__('odom_probe')
        self.create_subscription(Odometry, contract.ODOM, self.on_odom, contract.qos(contract.ODOM), raw=True)

    def on_odom(self, raw: bytes):
        print(time.monotonic_ns(), cdr.header_stamp_ns(raw, Odometry), flush=True)


def read(text: str):
    """(arrival_s, stamp_s) arrays of the lines a probe wrote (its log may hold other lines: ROS logging)."""
    import numpy as np
    complete = text[:text.rfind('\n') + 1]   # the probe may be writing the last line right now
    rows = [r for r in (line.split() for line in complete.splitlines()) if len(r) == 2 and all(x.isdigit() for x in r)]
    data = np.array(rows, dtype=np.int64).reshape(-1, 2)
    return data[:, 0] * 1e-9, data[:, 1] * 1e-9


if __name__ == '__main__':
    run_node('odom_probe', OdomProbe)
