"""mavlink_bridge: `cmd/attitude_thrust` -> SET_ATTITUDE_TARGET for PX4 / ArduPilot, telemetry -> ROS.

The node wires the parts (docs/bridge.md): the link and its receive thread (mavlink_client), which also decodes
and publishes telemetry (never waiting on the executor); the setpoint path (streamer: sent at once on arrival, in
a subscriber node of its own with its own thread, which also runs the keep-alive that re-sends); the hand-over
state machine and vehicle status under one lock (vehicle, handover); the autopilot backend (px4, ardupilot); the
commands to the vehicle (commands); the supervisor thread for the link, heartbeats, stream fall-backs and what
ends a hand-over (supervision); the arm / offboard / land services on the node's own single-threaded executor
(services); what each message read does (receive); the diagnostics (bridge_diagnostics).
"""

import sys
import threading
import time

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from rclpy.executors import ExternalShutdownException, ShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from std_msgs.msg import Bool
from std_srvs.srv import SetBool, Trigger

from quad_bridge.bridge_diagnostics import external_pose_status, link_status, setpoints_status
from quad_bridge.commands import VehicleCommander
from quad_bridge.external_pose import ExternalPoseFilter, ends_handover
from quad_bridge.geofence import Geofence
from quad_bridge.link import LinkState
from quad_bridge.mavlink_client import MavlinkClient
from quad_bridge.parameters import NAME, SPECS, bridge_config, external_pose_config, validate
from quad_bridge.peers import LinkPeers
from quad_bridge.receive import Receiver
from quad_bridge.services import BridgeServices
from quad_bridge.setpoint_path import SetpointPath
from quad_bridge.supervision import Supervisor
from quad_bridge.telemetry_publisher import HANDLERS, TelemetryPublisher, stamp
from quad_bridge.vehicle_state import Vehicle
from quad_common import contract, diagnostics
from quad_common.realtime import apply_or_report
from quad_common.ros.node_main import run_node
from quad_common.ros.rcl_serialized import SerializedPublisher
from quad_common.ros.ros_params import ParameterSet
from quad_common.signing_key import load_signing_key


class MavlinkBridge(Node):
    def __init__(self, **kwargs):
        """kwargs: rclpy Node's (context, namespace, parameter_overrides: a bridge inside a test process)."""
        super().__init__(NAME, **kwargs)
        self.params = ParameterSet(self, SPECS, validate=validate)
        p = self.params
        key = load_signing_key(p['signing_key_file']) if p['signing_key_file'] else None
        self.log = self.get_logger()
        self.vehicle = Vehicle(confirm_timeout_s=p['command_timeout_s'])
        if p['target_system']:
            self.vehicle.status.system = p['target_system']
        self.link = LinkState(p['link_timeout_s'])
        self.peers = LinkPeers()
        self.geofence = Geofence(p['geofence_enabled'], p['geofence_min_m'], p['geofence_max_m'],
                                 reaction_s=p['geofence_reaction_s'])
        self.t0 = time.monotonic()
        self.supervisor = Supervisor(self)
        self.bridge_services = BridgeServices(self)
        self.receiver = Receiver(self)   # the receive thread's: never waits on the executor
        self.stopping = threading.Event()
        # every DDS write of the bridge with the interpreter lock released (rcl_serialized: why)
        self.diag_pub = SerializedPublisher(self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS,
                                                                  contract.qos(contract.DIAGNOSTICS)))
        self.engaged_pub = SerializedPublisher(self.create_publisher(Bool, contract.ENGAGED,
                                                                     contract.qos(contract.ENGAGED)))
        self.engaged_lock = threading.Lock()
        self.engaged = None
        self.update_engaged()
        self.create_service(SetBool, 'arm', self.srv_arm)
        self.create_service(SetBool, 'offboard', self.srv_offboard)
        self.create_service(Trigger, 'land', self.srv_land)

        self.client = MavlinkClient(p['fcu_url'], p['source_system'], p['source_component'], self.receiver.on_mavlink,
                                    baud=p['baud'], signing_key=key, decode=('HEARTBEAT', *HANDLERS))
        self.commander = VehicleCommander(self.client, self.vehicle, p, bridge_config(p.values), self.log, self.now_s)
        self.telemetry = TelemetryPublisher(self, self.vehicle, self.client, self.supervisor.on_state,
                                            p['stream_grace_s'])
        self.setpoints = SetpointPath(self, self.may_stream, self.supervisor.on_stream_quiet)
        self.streamer = self.setpoints.streamer
        self.external_pose = None
        if p['external_pose_enabled']:
            self.external_pose = ExternalPoseFilter(external_pose_config(p.values))
            # A node and thread of its own: the services' executor waits in offboard's pre-stream (a second), and
            # the pose must reach the autopilot meanwhile (it timed out there when it shared that executor).
            name = f'{self.get_name()}_external_pose'
            self.external_pose_node = rclpy.create_node(name, namespace=self.get_namespace(), context=self.context,
                                                        cli_args=['--ros-args', '-r', f'__node:={name}'],
                                                        start_parameter_services=False)
            self.external_pose_node.create_subscription(PoseStamped, contract.EXTERNAL_POSE, self.on_external_pose,
                                                        contract.qos(contract.EXTERNAL_POSE))
            self.external_pose_node.create_subscription(Odometry, contract.EXTERNAL_ODOM, self.on_external_odometry,
                                                        contract.qos(contract.EXTERNAL_ODOM))
            self.external_pose_executor = SingleThreadedExecutor(context=self.context)
            self.external_pose_executor.add_node(self.external_pose_node)
            self.external_pose_thread = threading.Thread(target=self._spin_external_pose, name='external-pose-rx',
                                                         daemon=True)
        self.supervisor_thread = threading.Thread(target=self.supervisor.run, args=(self.stopping,),
                                                  name='supervisor', daemon=True)

        self.realtime, self.realtime_refused = self.apply_realtime(p['realtime_priority'])   # before our threads
        self.client.start()
        self.setpoints.start()
        if self.external_pose is not None:
            self.external_pose_thread.start()
        self.supervisor_thread.start()
        self.log.info(f'{NAME}: {p["fcu_url"]}, autopilot {p["autopilot"]}, keep-alive '
                      f'{p["setpoint_rate_hz"]} Hz, scheduling {self.realtime}')

    def apply_realtime(self, priority) -> tuple[str, bool]:
        """realtime_priority: every thread there is now (the executor's, Fast DDS's) under SCHED_FIFO; the
        receive, setpoint and supervisor threads started after it, and Fast DDS's later ones, inherit it.
        Refused by the system: an error naming the parameter and how to grant it, kept in the link's
        diagnostics (`realtime`, level WARN), and the bridge runs on under the ordinary scheduler."""
        return apply_or_report(priority, self.log.error)

    def now_s(self) -> float:
        return time.monotonic() - self.t0

    # --- may setpoints go out (quad_bridge.setpoint_path asks), vehicle/engaged ----------------------

    def may_stream(self) -> bool:
        return (self.link.state == LinkState.UP and not self.geofence.breached and self.vehicle.may_stream()
                and not self.link_refusal())

    def link_refusal(self) -> str:
        """Why no vehicle on this link may be commanded (quad_bridge.peers), or ''."""
        return self.peers.refusal(self.vehicle.status.system, self.params['target_component'],
                                  bool(self.params['target_system']), self.now_s())

    def update_engaged(self):
        """vehicle/engaged (latched): true while the vehicle flies our setpoints, i.e. the hand-over is ACTIVE (the
        vehicle accepted the mode we asked for and its heartbeat has shown it) and setpoints may go out; published
        on every change. The controller runs a plan's clock only while it is true (quad_control.loop), so a plan
        never runs ahead of a hand-over."""
        with self.engaged_lock:
            with self.vehicle.lock:
                engaged = self.vehicle.handover.engaged and self.may_stream()
            if engaged != self.engaged and self.context.ok():   # not once shut down (Ctrl-C)
                self.engaged = engaged
                self.engaged_pub.publish(Bool(data=engaged))
                if engaged or self.vehicle.handover.ended:
                    self.log.info(f'vehicle/engaged: {str(engaged).lower()}')

    # --- external pose (quad_bridge.external_pose): forwarded to the estimator, a fault ends the hand-over ----

    def _spin_external_pose(self):
        while not self.stopping.is_set() and self.context.ok():
            try:
                self.external_pose_executor.spin_once(timeout_sec=0.1)
            except (ExternalShutdownException, ShutdownException):
                return   # a stop signal shut the context down: destroy_node ends the rest

    def on_external_pose(self, msg):
        p, q = msg.pose.position, msg.pose.orientation
        self._forward_external_pose((p.x, p.y, p.z), (q.x, q.y, q.z, q.w), None, msg.header.stamp)

    def on_external_odometry(self, msg):
        """nav_msgs/Odometry: the twist is in the child (body) frame."""
        p, q, v = msg.pose.pose.position, msg.pose.pose.orientation, msg.twist.twist.linear
        self._forward_external_pose((p.x, p.y, p.z), (q.x, q.y, q.z, q.w), (v.x, v.y, v.z), msg.header.stamp)

    def _forward_external_pose(self, position, quaternion, velocity, header_stamp):
        stamp_ns = header_stamp.sec * 1_000_000_000 + header_stamp.nanosec
        try:
            pose = self.external_pose.offer(position, quaternion, velocity, stamp_ns, time.time_ns())
        except ValueError as exc:   # a zero / non-finite quaternion
            self.external_pose.fault = f'bad sample: {exc}'
            pose = None
        backend = self.vehicle.status.backend
        if pose is not None and backend is not None and self.link.state == LinkState.UP:
            for name, args in backend.external_pose_messages(pose):
                self.client.send(name, *args)
        elif ends_handover(self.external_pose.fault):
            self.supervisor.on_external_pose_fault(self.external_pose.fault)
        elif self.external_pose.fault:
            self.log.warn(f'external pose: {self.external_pose.fault}: not forwarded, the hand-over goes on '
                          f'({self.external_pose.dropped_late} so far)', throttle_duration_sec=1.0)

    # --- services (the node's executor): quad_bridge.services ----------------------------------------

    def srv_arm(self, request, response):
        response.success, response.message = self.bridge_services.arm(request.data)
        return response

    def srv_offboard(self, request, response):
        response.success, response.message = self.bridge_services.offboard(request.data)
        return response

    def srv_land(self, request, response):
        response.success, response.message = self.bridge_services.land()
        return response

    # --- diagnostics -------------------------------------------------------------------------------

    def publish_diagnostics(self):
        """`diagnostics`: quad_bridge.bridge_diagnostics of what the bridge knows now."""
        now = self.now_s()
        with self.vehicle.lock:
            s, h = self.vehicle.snapshot(), self.vehicle.handover
            phase, target, reason, ended = h.phase, h.target or '', h.reason, h.ended
            telemetry = self.telemetry.info(now)
            check = self.commander.param_check
        others, refusal = self.peers.other_vehicles(s.system, now), self.link_refusal()
        udp = self.client.udp_report()   # udpin: the vehicle's address, other senders, send errors
        counts = {**self.setpoints.counts(), 'stale_events': self.supervisor.stale_events}
        statuses = [
            link_status(s, self.link, telemetry, check, others, refusal, udp, self.client, self.realtime,
                        self.realtime_refused),
            setpoints_status(phase, target, reason, ended, phase != 'idle' and self.may_stream(), self.streamer,
                             counts, self.geofence)]
        if self.external_pose is not None:
            statuses.append(external_pose_status(self.external_pose, time.time_ns(),
                                                 self.supervisor.external_pose_faults))
        self.diag_pub.publish(diagnostics.array(stamp(time.time_ns()), statuses))

    def destroy_node(self):
        self.stopping.set()
        self.supervisor_thread.join(timeout=2.0)
        self.bridge_services.land_on_shutdown()   # the receive thread still reads the ACK
        self.setpoints.stop()
        if self.external_pose is not None:
            self.external_pose_thread.join(timeout=2.0)
            self.external_pose_executor.shutdown()
            self.external_pose_node.destroy_node()
        self.client.close()
        super().destroy_node()


# GIL hand-over interval: the setpoint thread (setpoints, the keep-alive) must get the interpreter within ~1 ms,
# not the default 5 ms, while the receive thread and the executor run.
GIL_SWITCH_INTERVAL_S = 0.001


def make_executor(node):
    """The node's own executor (services, parameters): single-threaded; the telemetry, setpoint, keep-alive and
    supervisor threads never wait on it."""
    return SingleThreadedExecutor(context=node.context)


def main(args=None):
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    run_node(NAME, MavlinkBridge, refused=(ValueError, OSError), make_executor=make_executor, args=args)


if __name__ == '__main__':
    main()
