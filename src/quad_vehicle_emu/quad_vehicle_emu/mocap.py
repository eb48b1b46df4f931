"""The emulated vehicle seen by a motion-capture system (`mavlink_vehicle --mocap-topic TOPIC`): its truth, not
its estimate, published as a lab's mocap driver publishes it (geometry_msgs/PoseStamped), so that the indoor
walk-through (docs/bridge.md "Indoor flight") can be rehearsed without a lab.

The frames are quad_sim.mocap's (noise, latency, lost frames: one model for the simulator and the emulator),
offered once per emulator loop tick at the physics' time; a frame measured at emulator time t is stamped with the
wall clock at t (wall0_ns + t: the clock the bridge and the controller stamp by), in `frame` (enu, or Y-up as
Motive publishes by default: quad_common.mocap_frames). rclpy is imported only when a topic is given: without
one the emulator is a MAVLink process and nothing else.
"""

from dataclasses import dataclass

import numpy as np

from quad_common.mocap_frames import FRAMES, from_enu
from quad_sim.mocap import MocapConfig, MotionCapture

# a lab system (Vicon, OptiTrack at 100 Hz): 1 mm and 2 mrad RMS, 10 ms from the capture to the driver's message
DEFAULTS = {'rate_hz': 100.0, 'position_noise_m': 0.001, 'attitude_noise_rad': 0.002, 'latency_s': 0.01}
Y_UP_FRAME_ID = 'mocap'   # a Y-up system's world frame is not ROS' map


@dataclass(frozen=True)
class Pose:
    stamp_ns: int             # wall clock at the capture instant
    position: np.ndarray      # world, in the stand-in's frame
    quaternion: np.ndarray    # body -> world (x, y, z, w), in the stand-in's frame


class MocapStandIn:
    """offer(t_s, truth) per loop tick -> the poses delivered by then, oldest first."""

    def __init__(self, config: MocapConfig, frame: str, wall0_ns: int, loop_rate_hz: float, seed: int = 0):
        if frame not in FRAMES:
            raise ValueError(f'--mocap-frame = {frame!r} refused: must be one of {", ".join(FRAMES)}')
        if not config.enabled:
            raise ValueError(f'--mocap-rate-hz = {config.rate_hz!r} refused: must be > 0')
        if config.rate_hz > loop_rate_hz:
            raise ValueError(f'--mocap-rate-hz = {config.rate_hz!r} refused: at most --loop-rate-hz '
                             f'({loop_rate_hz!r}): one frame per loop tick at most')
        self.frame, self.wall0_ns = frame, int(wall0_ns)
        self.capture = MotionCapture(config, seed=seed)

    def offer(self, time_s: float, position_enu, quaternion_enu) -> list[Pose]:
        poses = []
        for f in self.capture.offer(int(round(time_s * 1e9)), position_enu, quaternion_enu):
            position, quaternion = from_enu(self.frame, f.position, f.quaternion)
            poses.append(Pose(self.wall0_ns + f.stamp_ns, position, quaternion))
        return poses


class MocapPublisher:
    """MocapStandIn's poses on `topic` (a relative name resolves at the root, as a mocap driver's topic does),
    from a node of its own in this process's ROS domain (ROS_DOMAIN_ID); published from the emulator's loop, no
    executor (a publisher needs none)."""

    def __init__(self, stand_in: MocapStandIn, topic: str, node_name: str = 'mavlink_vehicle_mocap'):
        import rclpy
        from geometry_msgs.msg import PoseStamped

        from quad_common import contract

        self.stand_in, self._msg_type = stand_in, PoseStamped
        self.frame_id = contract.WORLD_FRAME if stand_in.frame == 'enu' else Y_UP_FRAME_ID
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(node_name, context=self.context, start_parameter_services=False)
        self.pub = self.node.create_publisher(PoseStamped, topic, contract.qos(contract.EXTERNAL_POSE))
        self.published = 0

    def offer(self, time_s: float, position_enu, quaternion_enu):
        for pose in self.stand_in.offer(time_s, position_enu, quaternion_enu):
            msg = self._msg_type()
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(pose.stamp_ns, 1_000_000_000)
            msg.header.frame_id = self.frame_id
            msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(v) for v in pose.position)
            q = msg.pose.orientation
            q.x, q.y, q.z, q.w = (float(v) for v in pose.quaternion)
            self.pub.publish(msg)
            self.published += 1

    def close(self):
        self.node.destroy_node()
        self.context.try_shutdown()
