"""mavlink_bridge: `cmd/attitude_thrust` -> SET_ATTITUDE_TARGET for PX4 / ArduPilot, telemetry -> ROS.

Parts (docs/bridge.md): the link and its receive thread (mavlink_client), which also decodes and publishes
telemetry (never waiting on the executor); the setpoint path (streamer: sent at once on arrival, in a
subscriber node of its own with its own thread, which also runs the keep-alive that re-sends); the hand-over
state machine and vehicle status under one lock (vehicle, handover); the autopilot backend (px4,
ardupilot); a supervisor thread for the link, heartbeats, stream fall-backs and diagnostics; services on
the node's own single-threaded executor.
"""

import dataclasses
import math
import sys
import threading
import time

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from rclpy.executors import ExternalShutdownException, ShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from std_msgs.msg import Bool
from std_srvs.srv import SetBool, Trigger

from quad_bridge import supervision
from quad_bridge.backend import (
    MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
    MAV_MODE_FLAG_SAFETY_ARMED,
    BridgeConfig,
    rate_interval_us,
)
from quad_bridge.backends import resolve
from quad_bridge.external_pose import ExternalPoseConfig, ExternalPoseFilter
from quad_bridge.geofence import BRAKE, BREACH, Geofence
from quad_bridge.handover import ACTIVE, PRESTREAM, PRESTREAM_S
from quad_bridge.link import LinkState, is_vehicle_heartbeat
from quad_bridge.mavlink_client import MavlinkClient, mavlink, result_name
from quad_bridge.parameters import SPECS, validate
from quad_bridge.peers import LinkPeers
from quad_bridge.setpoint_path import SetpointPath
from quad_bridge.telemetry_publisher import HANDLERS, TelemetryPublisher, stamp
from quad_bridge.vehicle_state import Vehicle
from quad_common import contract, diagnostics
from quad_common.node_main import run_node
from quad_common.realtime import apply_or_report
from quad_common.ros_params import ParameterSet
from quad_common.signing_key import load_signing_key

NAME = 'mavlink_bridge'
OFFBOARD_MIN_STREAM_HZ = 5.0  # on the wire over the pre-stream before asking PX4 for OFFBOARD (it needs > 2 Hz)
SUPERVISOR_PERIOD_S = 0.05
STATUSTEXT_WAIT_S = 0.5    # a refused command waits this long (wall) for the vehicle to say why (STATUSTEXT)


class MavlinkBridge(Node):
    def __init__(self, **kwargs):
        """kwargs: rclpy Node's (context, namespace, parameter_overrides: a bridge inside a test process)."""
        super().__init__(NAME, **kwargs)
        self.params = ParameterSet(self, SPECS, validate=validate)
        p = self.params
        key = load_signing_key(p['signing_key_file']) if p['signing_key_file'] else None
        # the parameters BridgeConfig holds, by their own names
        self.config = BridgeConfig(**{f.name: p[f.name] for f in dataclasses.fields(BridgeConfig)
                                      if f.name in p.values})
        self.flying_config = self.config   # after the vehicle's parameters were checked / adopted
        self.param_check = None
        self.param_read_lock = threading.Lock()
        self.vehicle = Vehicle(confirm_timeout_s=p['command_timeout_s'])
        if p['target_system']:
            self.vehicle.status.system = p['target_system']
        self.link = LinkState(p['link_timeout_s'])
        self.peers = LinkPeers()
        self.geofence = Geofence(p['geofence_enabled'], p['geofence_min_m'], p['geofence_max_m'],
                                 reaction_s=p['geofence_reaction_s'])
        self.t0 = time.monotonic()
        self.stale_events = 0
        self.lost_while_handed_over = False   # a link loss ended a hand-over (after_link_loss)
        self.stopping = threading.Event()
        self.diag_pub = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS, contract.qos(contract.DIAGNOSTICS))
        self.engaged_pub = self.create_publisher(Bool, contract.ENGAGED, contract.qos(contract.ENGAGED))
        self.engaged_lock = threading.Lock()
        self.engaged = None
        self.update_engaged()
        self.create_service(SetBool, 'arm', self.srv_arm)
        self.create_service(SetBool, 'offboard', self.srv_offboard)
        self.create_service(Trigger, 'land', self.srv_land)

        self.client = MavlinkClient(p['fcu_url'], p['source_system'], p['source_component'], self.on_mavlink,
                                    baud=p['baud'], signing_key=key, decode=('HEARTBEAT', *HANDLERS))
        self.telemetry = TelemetryPublisher(self, self.vehicle, self.client, self.on_state, p['stream_grace_s'])
        self.setpoints = SetpointPath(self, self.may_stream, self.on_stream_quiet)
        self.streamer = self.setpoints.streamer
        self.external_pose = None
        self.external_pose_faults = 0      # hand-overs ended by an external pose fault
        if p['external_pose_enabled']:
            self.external_pose = ExternalPoseFilter(ExternalPoseConfig(
                frame=p['external_pose_frame'], max_rate_hz=p['external_pose_rate_hz'],
                timeout_s=p['external_pose_timeout_s'], max_age_s=p['external_pose_max_age_s'],
                max_speed_m_s=p['external_pose_max_speed_mps'], jump_margin_m=p['external_pose_jump_margin_m']))
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
        self.supervisor = threading.Thread(target=self._supervise, name='supervisor', daemon=True)

        self.realtime, self.realtime_refused = self.apply_realtime(p['realtime_priority'])   # before our threads
        self.client.start()
        self.setpoints.start()
        if self.external_pose is not None:
            self.external_pose_thread.start()
        self.supervisor.start()
        self.get_logger().info(f'{NAME}: {p["fcu_url"]}, autopilot {p["autopilot"]}, keep-alive '
                               f'{p["setpoint_rate_hz"]} Hz, scheduling {self.realtime}')

    def apply_realtime(self, priority) -> tuple[str, bool]:
        """realtime_priority: every thread there is now (the executor's, Fast DDS's) under SCHED_FIFO; the
        receive, setpoint and supervisor threads started after it, and Fast DDS's later ones, inherit it.
        Refused by the system: an error naming the parameter and how to grant it, kept in the link's
        diagnostics (`realtime`, level WARN), and the bridge runs on under the ordinary scheduler."""
        return apply_or_report(priority, self.get_logger().error)

    def now_s(self) -> float:
        return time.monotonic() - self.t0

    # --- setpoint path (quad_bridge.setpoint_path): may it stream, what a quiet wire commands ----------

    def may_stream(self) -> bool:
        return (self.link.state == LinkState.UP and not self.geofence.breached and self.vehicle.may_stream()
                and not self.link_refusal())

    def link_refusal(self) -> str:
        """Why no vehicle on this link may be commanded (quad_bridge.peers), or ''."""
        return self.peers.refusal(self.vehicle.status.system, self.params['target_component'],
                                  bool(self.params['target_system']), self.now_s())

    def check_link_peers(self):
        """A second vehicle as our target, or an ambiguous target: the hand-over ends (supervisor)."""
        why = self.link_refusal()
        if why:
            with self.vehicle.lock:
                ended = self.vehicle.handover.end(why)
            if ended:
                self.get_logger().error(why)
                self.publish_diagnostics()

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
                    self.get_logger().info(f'vehicle/engaged: {str(engaged).lower()}')

    def on_stream_quiet(self, wire_age_s, input_age_s):
        """Nothing went out for setpoint_timeout_s: a vehicle in a mode that obeys SET_ATTITUDE_TARGET keeps flying
        the last one (ArduPilot for GUID_TIMEOUT, in GUIDED as in GUIDED_NOGPS), so command stale_action."""
        stale = input_age_s > self.params['setpoint_timeout_s']
        with self.vehicle.lock:
            if stale:
                self.stale_events += 1
                self.vehicle.handover.end(f'setpoints stale (none for {self.params["setpoint_timeout_s"]} s)')
            mode, current = self._stale_action_mode(), self.vehicle.mode_now(self.now_s())
        self.update_engaged()
        report = supervision.quiet_stream(stale, self.params['setpoint_timeout_s'], mode, current, self.link.state)
        if report.command is not None:
            self.set_mode(report.command, wait=False)
        if report.error:   # one severity per call site: rclpy refuses a site that changes it
            self.get_logger().error(report.message)
        else:
            self.get_logger().info(report.message)
        self.publish_diagnostics()

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
        elif self.external_pose.fault:
            self.on_external_pose_fault(self.external_pose.fault)

    def on_external_pose_fault(self, fault):
        """While the vehicle flies our setpoints on an estimate fed by the external pose, a fault (timeout, jump,
        late) ends the hand-over and commands stale_action: the estimate would drift or jump under it."""
        why = f'external pose: {fault}'
        with self.vehicle.lock:
            ended = self.vehicle.handover.end(why)
            mode = self._stale_action_mode() if ended else None
        if not ended:
            return
        self.external_pose_faults += 1
        self.update_engaged()
        command = supervision.hand_over_ended_command(mode, self.link.state)
        if command is not None:
            self.set_mode(command, wait=False)
        self.get_logger().error(f'{why}: hand-over ended' + (f', commanding {mode}' if mode else ''))
        self.publish_diagnostics()

    def _stale_action_mode(self) -> str | None:
        """The mode stale_action commands when the vehicle is armed in a mode that obeys SET_ATTITUDE_TARGET
        (it keeps flying the last one), else None. The mode is the one we commanded while its heartbeat is pending
        (after our own land, nothing but land). Under the vehicle lock."""
        s = self.vehicle.status
        return supervision.stale_action_mode(s.backend, s.armed, self.vehicle.mode_now(self.now_s()),
                                             self.params['stale_action'])

    def after_link_loss(self):
        """The link is back after a loss that ended a hand-over: a vehicle still armed in a mode that obeys
        SET_ATTITUDE_TARGET keeps flying the last one it got (ArduPilot: for GUID_TIMEOUT, then level with no
        climb, drifting) and nothing streams to it any more: the stream is stale, so command stale_action (the
        quiet-stream check may have fired while the link was down, when nothing could be commanded)."""
        with self.vehicle.lock:
            lost, self.lost_while_handed_over = self.lost_while_handed_over, False
            mode = self._stale_action_mode() if lost else None
            current = self.vehicle.mode_now(self.now_s())
            self.stale_events += mode is not None
        if mode is not None:
            self.get_logger().error(f'link back after a loss that ended the hand-over, the vehicle still in {current} '
                                    f'flying our last setpoint: commanding {mode}')
            self.set_mode(mode, wait=False)
            self.publish_diagnostics()

    # --- supervisor thread: link, heartbeats, telemetry fall-backs, diagnostics --------------------

    def _supervise(self):
        next_beat = 0.0
        while not self.stopping.wait(SUPERVISOR_PERIOD_S):
            try:
                now = self.now_s()
                self.update_engaged()
                if self.link.update(now, self.client.drained_s - self.t0) == 'lost':
                    with self.vehicle.lock:
                        if self.vehicle.handover.end('link lost'):
                            self.lost_while_handed_over = True
                    self.get_logger().error(f'vehicle link lost (nothing for {self.params["link_timeout_s"]} s)')
                    self.update_engaged()
                    self.publish_diagnostics()
                streams = self.telemetry.streams
                if streams is not None and self.link.state == LinkState.UP:
                    with self.vehicle.lock:
                        fallbacks = streams.update(now)
                    for group, messages in fallbacks:
                        self.get_logger().warn(streams.notes[-1])
                        self.request_messages(messages, self.group_rate_hz(group))
                self.check_link_peers()
                if self.external_pose is not None:
                    fault = self.external_pose.check_timeout(time.time_ns())
                    if fault and fault.startswith('timeout'):
                        self.on_external_pose_fault(fault)
                if now >= next_beat:
                    next_beat = now + 1.0
                    self.heartbeat_tick()
            except Exception as exc:  # never let the supervisor die silently
                self.get_logger().error(f'supervisor: {exc!r}', throttle_duration_sec=1.0)

    def heartbeat_tick(self):
        self.client.send('heartbeat', mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                         mavlink.MAV_STATE_ACTIVE)
        if self.vehicle.status.system is not None:
            self.telemetry.send_timesync()
        self.publish_diagnostics()

    def set_mode(self, name, wait=True):
        """DO_SET_MODE `name`; the bridge takes the vehicle to be in it from now until a heartbeat shows it (or the
        vehicle refuses it): quad_bridge.vehicle_state.Vehicle.mode_now. wait: return the ACK's result (None: none
        within command_timeout_s)."""
        s = self.vehicle.status
        main, sub = s.backend.mode_params(name)
        with self.vehicle.lock:
            self.vehicle.command_sent(name, self.now_s())
        result = self.client.command_long(s.system, self.params['target_component'], mavlink.MAV_CMD_DO_SET_MODE,
                                          [MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub],
                                          self.params['command_timeout_s'] if wait else None)
        if wait:
            with self.vehicle.lock:
                self.vehicle.command_answered(name, result == mavlink.MAV_RESULT_ACCEPTED)
        return result

    # --- on connect (a worker thread: it waits for ACKs and PARAM_VALUEs the receive thread delivers) ------

    def group_rate_hz(self, group):
        share = {g.name: g.share for g in self.vehicle.status.backend.telemetry}[group]
        return self.params['telemetry_rate_hz'] * share if share else 2.0

    def request_messages(self, messages, rate_hz):
        s = self.vehicle.status
        for name in messages:
            msg_id = getattr(mavlink, f'MAVLINK_MSG_ID_{name}')
            result = self.client.command_long(s.system, self.params['target_component'],
                                              mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                                              [msg_id, rate_interval_us(rate_hz)], 1.0)
            if result not in (mavlink.MAV_RESULT_ACCEPTED, None):
                self.get_logger().warn(f'{name} at {rate_hz:.0f} Hz: {result_name(result)}')

    def on_connect(self):
        s = self.vehicle.status
        streams = self.telemetry.streams
        with self.vehicle.lock:
            streams.reset(self.now_s())
        for group in s.backend.telemetry:
            self.request_messages(streams.current(group.name), self.group_rate_hz(group.name))
        self.read_vehicle_params()

    def read_vehicle_params(self):
        """PARAM_REQUEST_READ of the backend's semantic parameters; the check decides whether offboard may run.
        One read at a time (on connect and from `offboard` may overlap; their PARAM_VALUE waiters would collide)."""
        with self.param_read_lock:
            return self._read_vehicle_params()

    def _read_vehicle_params(self):
        s = self.vehicle.status
        values = {}
        if self.params['vehicle_params'] != 'ignore':
            answers = self.client.read_params(s.system, self.params['target_component'],
                                              s.backend.param_names(self.config), self.params['command_timeout_s'])
            values = {n: s.backend.decode_param(v, t) for n, (v, t) in answers.items()}
        check = s.backend.check_params(values, self.config, self.params['vehicle_params'])
        with self.vehicle.lock:
            s.params = values
            self.param_check = check
            self.flying_config = check.config
        for line in check.problems:
            self.get_logger().error(f'offboard will be refused: {line}')
        for line in check.notes:
            self.get_logger().warn(line)
        return check

    # --- services (the node's executor) ------------------------------------------------------------

    def _ready(self, response):
        s = self.vehicle.status
        signing = self.client.signing_problem()
        if s.system is None or s.backend is None:
            response.success, response.message = False, 'no vehicle heartbeat yet' + (f': {signing}' if signing
                                                                                      else '')
            return False
        if signing:
            response.success, response.message = False, signing
            return False
        if self.link.state != LinkState.UP:
            response.success, response.message = False, f'link {self.link.state}'
            return False
        why = self.link_refusal()
        if why:
            response.success, response.message = False, why
            return False
        return True

    def _answer(self, response, what, result, sent_ns):
        """The service's answer to a command sent at sent_ns (wall); refused, with what the vehicle said since in
        its STATUSTEXTs (the autopilots give the reason there, beside the COMMAND_ACK)."""
        response.success = result == mavlink.MAV_RESULT_ACCEPTED
        response.message = f'{what}: {result_name(result)}'
        if not response.success and result is not None:
            said = self.vehicle.texts.wait_since(sent_ns, STATUSTEXT_WAIT_S)
            if said:
                response.message += ': the vehicle says ' + ' / '.join(f'"{t}"' for t in said)
        return response

    @staticmethod
    def _refuse(response, message):
        response.success, response.message = False, message
        return response

    def srv_arm(self, request, response):
        if not self._ready(response):
            return response
        if request.data:
            with self.vehicle.lock:
                s = self.vehicle.status
                reason = s.backend.arm_refusal(s.mode, self.vehicle.handover.active)
            if reason:
                return self._refuse(response, f'arm refused: {reason}')
        else:
            with self.vehicle.lock:
                flying_ours = self.vehicle.handover.active
            if flying_ours:  # any node of the domain may call this service (docs/bridge.md, who can command)
                return self._refuse(response, 'disarm refused: the vehicle is flying our setpoints; call land '
                                              'first (a disarm in the air drops it)')
        sent_ns = time.time_ns()
        result = self.client.command_long(self.vehicle.status.system, self.params['target_component'],
                                          mavlink.MAV_CMD_COMPONENT_ARM_DISARM, [1.0 if request.data else 0.0],
                                          self.params['command_timeout_s'])
        return self._answer(response, 'arm' if request.data else 'disarm', result, sent_ns)

    def srv_offboard(self, request, response):
        if not self._ready(response):
            return response
        backend = self.vehicle.status.backend
        if not request.data:
            with self.vehicle.lock:
                self.vehicle.handover.end('offboard false')
                current = self.vehicle.mode_now(self.now_s())
            self.update_engaged()
            if current == backend.land_mode:   # after land nothing but land
                response.success, response.message = True, f'vehicle in {current}: nothing commanded'
                return response
            mode = backend.hold_mode('hold')
            sent_ns = time.time_ns()
            return self._answer(response, f'mode {mode}', self.set_mode(mode), sent_ns)
        check = self.param_check
        if check is None or self.params['vehicle_params'] != 'ignore':
            # read again: the vehicle's values now, not connect's (MPC_THR_HOVER may have been set on the vehicle since)
            check = self.read_vehicle_params()
        if check.problems:
            return self._refuse(response, 'offboard refused: ' + '; '.join(check.problems))
        if self.external_pose is not None and self.external_pose.check_timeout(time.time_ns()):
            return self._refuse(response, f'offboard refused: external pose {self.external_pose.fault}')
        if not self.streamer.fresh():
            refused = self.setpoints.refused_sources()
            return self._refuse(response, 'no live setpoint stream: publish cmd/attitude_thrust first' + (
                f' (refused, not setpoint_source {self.params["setpoint_source"]}: {refused})' if refused else ''))
        target = backend.offboard_mode
        with self.vehicle.lock:
            self.vehicle.handover.request(target, backend.prestream, self.now_s())
        self.geofence.reset()
        self.streamer.kick()
        if backend.prestream:
            refusal = self._prestream()
            if refusal:
                return self._refuse(response, refusal)
        sent_ns = time.time_ns()
        result = self.set_mode(target)
        with self.vehicle.lock:
            self.vehicle.handover.acknowledged(result == mavlink.MAV_RESULT_ACCEPTED, result_name(result),
                                               self.now_s(), self.vehicle.status.mode)
        self.update_engaged()
        self.streamer.kick()
        self.publish_diagnostics()
        return self._answer(response, f'mode {target}', result, sent_ns)

    def _prestream(self) -> str:
        """Setpoints on the wire for PRESTREAM_S before the switch (quad_bridge.handover); the reason to refuse
        offboard, or ''. Ends early when the hand-over ended meanwhile (link lost, setpoints stale)."""
        deadline = time.monotonic() + PRESTREAM_S
        while time.monotonic() < deadline and self.vehicle.handover.phase == PRESTREAM:
            time.sleep(0.02)
        rate_hz = self.streamer.rate_hz()   # not under vehicle.lock: the streamer takes it under its own lock
        with self.vehicle.lock:
            handover = self.vehicle.handover
            if handover.phase != PRESTREAM:
                return f'offboard refused during the pre-stream: {handover.reason}'
            if rate_hz < OFFBOARD_MIN_STREAM_HZ:
                handover.end(f'the pre-stream did not reach {OFFBOARD_MIN_STREAM_HZ} Hz')
                return f'no live setpoint stream: {rate_hz:.1f} Hz sent'
        return ''

    def srv_land(self, request, response):
        if not self._ready(response):
            return response
        with self.vehicle.lock:
            self.vehicle.handover.end('land')
        self.update_engaged()
        mode = self.vehicle.status.backend.land_mode
        sent_ns = time.time_ns()
        return self._answer(response, f'mode {mode}', self.set_mode(mode), sent_ns)

    # --- vehicle -> ROS (receive thread: decodes and publishes itself, never waits on the executor) ----

    def on_mavlink(self, msg):
        """Every message read (a quad_bridge.mavlink_client.Counted where the kind is not decoded)."""
        now, system, component, seq = self.now_s(), msg.get_srcSystem(), msg.get_srcComponent(), msg.get_seq()
        ours = system == self.vehicle.status.system
        if ours and component == self.params['target_component']:
            self.link.message(now, seq)
        heartbeat = msg.get_type() == 'HEARTBEAT'
        self.peers.seen(system, component, seq, now, heartbeat and is_vehicle_heartbeat(msg.type, msg.autopilot))
        if heartbeat:
            self.on_heartbeat(msg)
        elif ours:  # only our vehicle's telemetry is used
            self.telemetry.handle(msg, now)

    def on_heartbeat(self, msg):
        s = self.vehicle.status
        if not is_vehicle_heartbeat(msg.type, msg.autopilot):
            return
        with self.vehicle.lock:
            if s.system is None:
                s.system = msg.get_srcSystem()
            if msg.get_srcSystem() != s.system or msg.get_srcComponent() != self.params['target_component']:
                return
            self.client.answer_only(s.system, msg.get_srcComponent())   # a udpin link answers only its address
            if s.backend is None:
                try:
                    s.backend = resolve(self.params['autopilot'], msg.autopilot)
                except ValueError as exc:
                    self.get_logger().error(str(exc), throttle_duration_sec=5.0)
                    return
                self.telemetry.start(s.backend)
            change, ended = self.vehicle.heartbeat(msg.custom_mode, bool(msg.base_mode & MAV_MODE_FLAG_SAFETY_ARMED),
                                                   self.now_s())
        event = self.link.heartbeat(self.now_s())
        if change:
            self.get_logger().info(f'vehicle mode {change}')
        self.update_engaged()   # engaged once a heartbeat shows the mode we asked for
        if ended:
            self.get_logger().warn(ended)
            self.publish_diagnostics()
        if event == 'reconnected':
            self.after_link_loss()
        if event:
            self.get_logger().info(f'vehicle {s.system} {event}: {s.backend.name}, mode {s.mode}')
            self.telemetry.link_up()
            threading.Thread(target=self.on_connect, name='on-connect', daemon=True).start()

    def on_state(self, state):
        """Every odometry state: the geofence (quad_bridge.geofence: braking setpoints before the wall, then land)."""
        if not self.geofence.enabled:
            return
        action = self.geofence.update(state.position, state.velocity, self.vehicle.status.armed, bool(self.engaged),
                                      math.radians(self.params['max_tilt_deg']))
        if action == BRAKE:
            self.get_logger().error(f'geofence ahead: braking at {np.round(state.position, 2).tolist()}, '
                                    f'{np.linalg.norm(state.velocity):.2f} m/s')
            self.streamer.kick()   # the braking setpoint (quad_bridge.setpoint_path) on the wire now
        elif action == BREACH:
            with self.vehicle.lock:
                self.vehicle.handover.end(f'geofence: {self.geofence.breach_reason}')
            self.update_engaged()
            where = np.round(state.position, 2).tolist()
            self.get_logger().error(f'geofence: {self.geofence.breach_reason} at {where}: streaming stopped, landing')
            self.set_mode(self.vehicle.status.backend.land_mode, wait=False)

    # --- diagnostics -------------------------------------------------------------------------------

    def publish_diagnostics(self):
        now = self.now_s()
        with self.vehicle.lock:
            s, h = self.vehicle.snapshot(), self.vehicle.handover
            phase, target, reason, ended = h.phase, h.target or '', h.reason, h.ended
            telemetry = self.telemetry.info(now)
            check = self.param_check
        others, refusal = self.peers.other_vehicles(s.system, now), self.link_refusal()
        udp = self.client.udp_report()   # udpin: the vehicle's address, other senders, send errors
        level = supervision.link_level(
            self.link.state, bool(telemetry['missing_streams'] or (check and check.problems) or others
                                  or self.realtime_refused or udp.get('other_senders')),
            bool(refusal or self.client.signing_problem()))
        link = diagnostics.status(f'{NAME}: link', level, f'link {self.link.state}', {
            'target_system': s.system, 'autopilot': s.backend.name if s.backend else '?', 'mode': s.mode,
            'armed': s.armed, 'prearm_ready': '' if s.prearm_ready is None else s.prearm_ready,
            'rtt_ms': f'{s.rtt_ms:.2f}', **telemetry,
            'vehicle_params': ', '.join(f'{k}={v:g}' for k, v in sorted(s.params.items())),
            'param_problems': '; '.join(check.problems) if check else '',
            'param_notes': '; '.join(check.notes) if check else '',
            'packet_loss_pct': f'{self.link.packet_loss_pct():.2f}', 'losses': self.link.losses,
            'reconnects': self.link.reconnects, 'bad_data': self.client.bad_data,
            'handler_errors': self.client.handler_errors, 'other_vehicles': ', '.join(map(str, others)),
            'link_refusal': refusal, 'signing': self.client.signing_problem() or
            ('on' if self.client.signing else 'off'), 'realtime': self.realtime, **udp})
        st = self.streamer
        counts = {**self.setpoints.counts(), 'stale_events': self.stale_events}
        sp_level = supervision.setpoints_level(self.stale_events, self.geofence.breached,
                                               counts.get('refused_source', 0))
        setpoints = diagnostics.status(f'{NAME}: setpoints', sp_level, reason, {
            'handover': phase, 'target_mode': target, 'handovers_ended': ended,
            'streaming': phase != 'idle' and self.may_stream(), 'rate_hz': f'{st.rate_hz():.1f}',
            'received': st.received, 'sent': st.sent_total, 'keepalives': st.keepalives,
            'superseded': st.superseded, **counts,
            'geofence_breached': self.geofence.breached, 'geofence_braking': self.geofence.braking})
        statuses = [link, setpoints]
        if self.external_pose is not None:
            ep, now_ns = self.external_pose, time.time_ns()
            statuses.append(diagnostics.status(
                f'{NAME}: external pose', diagnostics.WARN if ep.fault else diagnostics.OK, ep.fault or 'forwarding',
                {'frame': ep.config.frame, 'rate_hz': f'{ep.rate_hz(now_ns):.1f}',
                 'age_ms': f'{ep.last_age_s * 1e3:.1f}', 'forwarded': ep.forwarded, 'dropped_rate': ep.dropped_rate,
                 'fault': ep.fault or '', 'handovers_ended': self.external_pose_faults}))
        self.diag_pub.publish(diagnostics.array(stamp(time.time_ns()), statuses))

    def land_on_shutdown(self):
        """Shut down (SIGINT, SIGTERM) while the vehicle flies our setpoints: command what `land` commands and wait
        for its ACK (command_timeout_s at most) before the link closes. Left alone, PX4 falls to its offboard-loss
        failsafe after COM_OF_LOSS_T, and ArduPilot flies the last attitude target for GUID_TIMEOUT, then level
        with no climb, drifting. Returns the ACK's result, or None when nothing was commanded."""
        with self.vehicle.lock:
            s, handover = self.vehicle.status, self.vehicle.handover
            flying = s.backend is not None and (handover.phase == ACTIVE or (
                handover.active and s.backend.obeys_setpoints(self.vehicle.mode_now(self.now_s()))))
            if not flying:
                return None
            handover.end('the bridge is shutting down')
        if self.link.state != LinkState.UP:
            self.get_logger().error(f'shutting down with the vehicle in {s.mode} flying our setpoints and the link '
                                    f'{self.link.state}: nothing can be commanded (the vehicle\'s own failsafe acts)')
            return None
        mode = s.backend.land_mode
        self.get_logger().warn(f'shutting down with the vehicle flying our setpoints: commanding {mode}')
        result = self.set_mode(mode)
        if result == mavlink.MAV_RESULT_ACCEPTED:
            self.get_logger().info(f'{mode}: {result_name(result)}')
        else:
            self.get_logger().error(f'{mode}: {result_name(result)}')
        return result

    def destroy_node(self):
        self.stopping.set()
        self.supervisor.join(timeout=2.0)
        self.land_on_shutdown()   # the receive thread still reads the ACK
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
