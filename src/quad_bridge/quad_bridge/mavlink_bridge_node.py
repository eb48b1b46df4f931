"""mavlink_bridge: `cmd/attitude_thrust` -> SET_ATTITUDE_TARGET for PX4 / ArduPilot, telemetry -> ROS.

Parts (docs/bridge.md): the link and its receive thread (mavlink_client), which also decodes and publishes
telemetry (never waiting on the executor); the setpoint path (streamer: sent at once on arrival, in a
subscriber node of its own with its own executor thread; a keep-alive thread re-sends); the hand-over
state machine and vehicle status under one lock (vehicle, handover); the autopilot backend (px4,
ardupilot); a supervisor thread for the link, heartbeats, stream fall-backs and diagnostics; services on
the node's own single-threaded executor.
"""

import math
import sys
import threading
import time

import numpy as np
import rclpy
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry
from rclpy.node import Node
from sensor_msgs.msg import BatteryState, Imu
from std_srvs.srv import SetBool, Trigger

from quad_bridge import frames
from quad_bridge.backend import (
    MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
    MAV_MODE_FLAG_SAFETY_ARMED,
    ThrustConfig,
    backend_for,
    rate_interval_us,
)
from quad_bridge.clock import ClockMapper
from quad_bridge.link import LinkState, is_vehicle_heartbeat, load_signing_key, resolve_autopilot
from quad_bridge.mavlink_client import MAV_COMP_ID_ONBOARD_COMPUTER, MavlinkClient, check_fcu_url, mavlink, result_name
from quad_bridge.safety import Geofence
from quad_bridge.setpoint import check_setpoint
from quad_bridge.streamer import SetpointStreamer
from quad_bridge.streams import StreamSelector
from quad_bridge.telemetry import imu_flu, state_from_local_position, state_from_odometry, time_us
from quad_bridge.vehicle import Vehicle
from quad_common import cdr, conversions, diagnostics
from quad_common.hot_path import HotPathExecutor
from quad_common.node_main import run_node
from quad_common.params import Param, ParameterSet

NAME = 'mavlink_bridge'
PARAMS = [
    Param('fcu_url', 'udpin:0.0.0.0:14540', 'pymavlink connection: udpin:/udpout:/tcp:HOST:PORT or serial device',
          read_only=True),
    Param('baud', 57600, 'serial baud rate (serial fcu_url only)', min=1200, max=4000000, read_only=True),
    Param('autopilot', 'auto', 'auto (from HEARTBEAT.autopilot) | px4 | ardupilot',
          choices=('auto', 'px4', 'ardupilot'), read_only=True),
    Param('target_system', 0, 'vehicle system id; 0 = the first vehicle heartbeat', min=0, max=255, read_only=True),
    Param('target_component', 1, 'vehicle component id (autopilot)', min=0, max=255, read_only=True),
    Param('source_system', 1, 'our MAVLink system id', min=1, max=255, read_only=True),
    Param('source_component', MAV_COMP_ID_ONBOARD_COMPUTER, 'our MAVLink component id (191 = onboard computer)',
          min=1, max=255, read_only=True),
    Param('setpoint_rate_hz', 50.0, 'keep-alive rate: the newest setpoint is re-sent when none went out for a period',
          min=2.0, max=1000.0, read_only=True),
    Param('setpoint_timeout_s', 0.5, 'nothing on the wire for this long: the stream is stale, stale_action',
          min=0.02, max=10.0, read_only=True),
    Param('stale_action', 'land', 'what a stale stream commands: land | hold (ArduPilot always lands)',
          choices=('land', 'hold')),
    Param('link_timeout_s', 2.0, 'no vehicle heartbeat for this long: link lost', min=0.2, max=30.0),
    Param('hover_throttle', 0.5,
          'normalised thrust that hovers the vehicle (PX4 MPC_THR_HOVER, ArduPilot MOT_THST_HOVER)',
          min=0.05, max=0.95, read_only=True),
    Param('hover_throttle_tolerance', 0.03, 'largest |vehicle hover thrust - hover_throttle| offboard accepts',
          min=0.0, max=0.5, read_only=True),
    Param('vehicle_params', 'check',
          'check: refuse offboard when the vehicle\'s parameters contradict ours | adopt: fly with the vehicle\'s '
          '| ignore: do not read them', choices=('check', 'adopt', 'ignore'), read_only=True),
    Param('max_tilt_deg', 35.0, 'setpoints tilted further are clamped to this keeping their vertical acceleration',
          min=1.0, max=85.0),
    Param('ardupilot_thrust_mode', 'thrust', 'thrust (GUID_OPTIONS bit 3 set) | climb_rate (bit 3 clear)',
          choices=('thrust', 'climb_rate'), read_only=True),
    Param('ardupilot_speed_up_mps', 2.5, 'WPNAV_SPEED_UP: climb rate at thrust 1 (climb_rate mode)', min=0.1, max=20.0,
          read_only=True),
    Param('ardupilot_speed_down_mps', 1.5, 'WPNAV_SPEED_DN: descent rate at thrust 0 (climb_rate mode)',
          min=0.1, max=20.0, read_only=True),
    Param('climb_rate_lead_s', 0.5, 'climb_rate mode: v_z command = v_z + lead * (f cos(tilt) - g)', min=0.01, max=5.0,
          read_only=True),
    Param('telemetry_rate_hz', 50.0, 'rate requested with MAV_CMD_SET_MESSAGE_INTERVAL for odometry/IMU',
          min=1.0, max=500.0, read_only=True),
    Param('stream_grace_s', 3.0, 'a requested telemetry message not seen for this long: fall back, then warn',
          min=0.5, max=30.0, read_only=True),
    Param('command_timeout_s', 3.0, 'how long a service waits for COMMAND_ACK (and PARAM_VALUE)', min=0.1, max=30.0),
    Param('geofence_enabled', False, 'land when the vehicle leaves the box geofence_min_m..geofence_max_m (ENU)'),
    Param('geofence_min_m', [-50.0, -50.0, -1.0], 'geofence box lower corner (map, ENU)', length=3),
    Param('geofence_max_m', [50.0, 50.0, 30.0], 'geofence box upper corner (map, ENU)', length=3),
    Param('signing_key_file', '', 'MAVLink 2 signing key file (64 hex chars or a passphrase); empty = unsigned',
          read_only=True),
]
OFFBOARD_MIN_STREAM_HZ = 5.0  # sent before asking PX4 for OFFBOARD (it needs > 2 Hz)
PRESTREAM_WAIT_S = 2.0
SUPERVISOR_PERIOD_S = 0.05
# DDS keeps this many setpoints for us while the interpreter is busy elsewhere (its reader thread is not held by
# the GIL): a 0.1 s stall at 500 Hz loses none (bench/bench_bridge.py; depth 10 lost 3-5 % at 100-500 Hz).
SETPOINT_QUEUE_DEPTH = 100
ATTITUDE_RATES_IGNORE = (mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE
                         | mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE
                         | mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_YAW_RATE_IGNORE)
TIMESTAMPED = ('ATTITUDE_QUATERNION', 'LOCAL_POSITION_NED', 'ODOMETRY', 'HIGHRES_IMU', 'SCALED_IMU', 'RAW_IMU')


def _validate(values):
    reason = check_fcu_url(values['fcu_url'])
    if reason:
        raise ValueError(reason)
    if any(lo >= hi for lo, hi in zip(values['geofence_min_m'], values['geofence_max_m'])):
        raise ValueError(f'geofence_min_m = {values["geofence_min_m"]} must be below geofence_max_m = '
                         f'{values["geofence_max_m"]} on every axis')


def _stamp(ns: int) -> Time:
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


class MavlinkBridge(Node):
    def __init__(self):
        super().__init__(NAME)
        self.params = ParameterSet(self, PARAMS, validate=_validate)
        p = self.params
        key = load_signing_key(p['signing_key_file']) if p['signing_key_file'] else None
        self.config = ThrustConfig(hover_throttle=p['hover_throttle'], hover_tolerance=p['hover_throttle_tolerance'],
                                   thrust_mode=p['ardupilot_thrust_mode'], speed_up_mps=p['ardupilot_speed_up_mps'],
                                   speed_down_mps=p['ardupilot_speed_down_mps'],
                                   climb_rate_lead_s=p['climb_rate_lead_s'], setpoint_rate_hz=p['setpoint_rate_hz'],
                                   setpoint_timeout_s=p['setpoint_timeout_s'])
        self.flying_config = self.config   # after the vehicle's parameters were checked / adopted
        self.param_check = None
        self.param_read_lock = threading.Lock()
        self.vehicle = Vehicle(confirm_timeout_s=p['command_timeout_s'])
        if p['target_system']:
            self.vehicle.status.system = p['target_system']
        self.link = LinkState(p['link_timeout_s'])
        self.geofence = Geofence(p['geofence_enabled'], p['geofence_min_m'], p['geofence_max_m'])
        self.clock = ClockMapper()
        self.streams = None                # StreamSelector once the backend is known
        self.t0 = time.monotonic()
        self.counts_lock = threading.Lock()
        self.refused = self.clamped = self.clamp_short = self.stale_events = 0
        self.timesync_ts1 = None
        self.stopping = threading.Event()
        self.handlers = {'ATTITUDE_QUATERNION': self.on_attitude_quaternion,
                         'LOCAL_POSITION_NED': self.on_local_position_ned, 'ODOMETRY': self.on_odometry,
                         'HIGHRES_IMU': self.on_imu, 'SCALED_IMU': self.on_imu, 'RAW_IMU': self.on_imu,
                         'SYS_STATUS': self.on_sys_status, 'BATTERY_STATUS': self.on_battery_status,
                         'TIMESYNC': self.on_timesync, 'STATUSTEXT': self.on_statustext}

        qos = 10
        self.odom_pub = self.create_publisher(Odometry, 'odom', qos)
        self.odom_packer = cdr.OdometryPacker()
        self.imu_pub = self.create_publisher(Imu, 'imu', qos)
        self.battery_pub = self.create_publisher(BatteryState, 'battery', qos)
        self.diag_pub = self.create_publisher(DiagnosticArray, 'diagnostics', qos)
        self.create_service(SetBool, 'arm', self.srv_arm)
        self.create_service(SetBool, 'offboard', self.srv_offboard)
        self.create_service(Trigger, 'land', self.srv_land)

        self.client = MavlinkClient(p['fcu_url'], p['source_system'], p['source_component'], self.on_mavlink,
                                    baud=p['baud'], signing_key=key)
        self.streamer = SetpointStreamer(self.send_setpoint, self.may_stream, p['setpoint_rate_hz'],
                                         p['setpoint_timeout_s'], self.on_stream_quiet, on_error=self._stream_error)
        # The setpoint path has a node and an executor thread of its own: services waiting for an ACK never
        # delay a setpoint, and a setpoint never waits for the services.
        self.setpoint_node = rclpy.create_node(f'{NAME}_setpoints', namespace=self.get_namespace(),
                                               context=self.context, start_parameter_services=False)
        self.setpoint_sub = self.setpoint_node.create_subscription(Imu, 'cmd/attitude_thrust', self.on_setpoint,
                                                                   SETPOINT_QUEUE_DEPTH, raw=True)
        self.setpoint_executor = HotPathExecutor(lambda: ([self.setpoint_sub], []), context=self.context)
        self.setpoint_executor.add_node(self.setpoint_node)
        self.setpoint_thread = threading.Thread(target=self._spin_setpoints, name='setpoint-rx', daemon=True)
        self.supervisor = threading.Thread(target=self._supervise, name='supervisor', daemon=True)

        self.client.start()
        self.streamer.start()
        self.setpoint_thread.start()
        self.supervisor.start()
        self.get_logger().info(f'{NAME}: {p["fcu_url"]}, autopilot {p["autopilot"]}, keep-alive '
                               f'{p["setpoint_rate_hz"]} Hz')

    def now_s(self) -> float:
        return time.monotonic() - self.t0

    # --- setpoint path (setpoint-rx thread, keep-alive thread) ------------------------------------

    def _spin_setpoints(self):
        while self.context.ok() and not self.stopping.is_set():
            try:
                self.setpoint_executor.spin_once(timeout_sec=0.2)
            except Exception:
                if self.context.ok() and not self.stopping.is_set():
                    raise

    def on_setpoint(self, raw: bytes):
        """A serialized cmd/attitude_thrust (quad_common.cdr: no Python message object on the hot path)."""
        with self.vehicle.lock:
            backend = self.vehicle.status.backend
        f_max = backend.max_specific_force(self.flying_config) if backend else math.inf
        try:
            sp, clamped, kept = check_setpoint(cdr.imu_to_setpoint(raw), math.radians(self.params['max_tilt_deg']),
                                               f_max)
        except ValueError as exc:
            with self.counts_lock:
                self.refused += 1
            self.get_logger().warn(f'setpoint refused ({self.refused} so far): {exc}', throttle_duration_sec=1.0)
            return
        if clamped:
            with self.counts_lock:
                self.clamped += 1
                self.clamp_short += not kept
            self.get_logger().warn(f'setpoint tilt clamped to {self.params["max_tilt_deg"]} deg ({self.clamped} so '
                                   f'far){"" if kept else ": vertical acceleration NOT kept, thrust at its limit"}',
                                   throttle_duration_sec=1.0)
        self.streamer.submit(sp)

    def may_stream(self) -> bool:
        return self.link.state == LinkState.UP and not self.geofence.breached and self.vehicle.may_stream()

    def send_setpoint(self, sp):
        """One SET_ATTITUDE_TARGET (NED/FRD, the backend's thrust semantics)."""
        with self.vehicle.lock:
            s = self.vehicle.status
            vz = s.state.velocity[2] if s.state is not None else 0.0
            system, thrust = s.system, s.backend.thrust(sp, self.flying_config, vz)
        if sp.body_rates is None:
            mask, rates = ATTITUDE_RATES_IGNORE, (0.0, 0.0, 0.0)
        else:
            mask, rates = 0, tuple(map(float, frames.body_flu_frd(sp.body_rates)))
        q = frames.to_mavlink_quaternion(frames.quaternion_enu_to_ned(sp.quaternion))
        self.client.send('set_attitude_target', int(self.now_s() * 1000) & 0xFFFFFFFF, system,
                         self.params['target_component'], mask, q, *rates, thrust)

    def on_stream_quiet(self, wire_age_s, input_age_s):
        """Nothing went out for setpoint_timeout_s: a vehicle in a mode that obeys SET_ATTITUDE_TARGET keeps flying
        the last one (ArduPilot for GUID_TIMEOUT, in GUIDED as in GUIDED_NOGPS), so command stale_action."""
        stale = input_age_s > self.params['setpoint_timeout_s']
        with self.vehicle.lock:
            s = self.vehicle.status
            if stale:
                self.stale_events += 1
                self.vehicle.handover.end(f'setpoints stale (none for {self.params["setpoint_timeout_s"]} s)')
            obeying = s.backend is not None and s.armed and s.backend.obeys_setpoints(s.mode)
            mode = s.backend.hold_mode(self.params['stale_action']) if s.backend else None
            current = s.mode
        action = f'nothing commanded (vehicle in {current or "?"}, not flying our setpoints)'
        if obeying and self.link.state == LinkState.UP:
            self.set_mode(mode, wait=False)
            action = f'commanding {mode} (the vehicle in {current} keeps flying the last setpoint)'
        what = (f'setpoints stale (none for {self.params["setpoint_timeout_s"]} s)' if stale
                else 'setpoint stream stopped')
        (self.get_logger().error if stale or obeying else self.get_logger().info)(f'{what}: {action}')
        self.publish_diagnostics()

    def _stream_error(self, exc):
        self.get_logger().error(f'setpoint keep-alive: {exc!r}', throttle_duration_sec=1.0)

    # --- supervisor thread: link, heartbeats, telemetry fall-backs, diagnostics --------------------

    def _supervise(self):
        next_beat = 0.0
        while not self.stopping.wait(SUPERVISOR_PERIOD_S):
            try:
                now = self.now_s()
                if self.link.update(now) == 'lost':
                    with self.vehicle.lock:
                        self.vehicle.handover.end('link lost')
                    self.get_logger().error(f'vehicle heartbeat lost (none for {self.params["link_timeout_s"]} s)')
                    self.publish_diagnostics()
                if self.streams is not None and self.link.state == LinkState.UP:
                    with self.vehicle.lock:
                        fallbacks = self.streams.update(now)
                    for group, messages in fallbacks:
                        self.get_logger().warn(self.streams.notes[-1])
                        self.request_messages(messages, self.group_rate_hz(group))
                if now >= next_beat:
                    next_beat = now + 1.0
                    self.heartbeat_tick()
            except Exception as exc:  # never let the supervisor die silently
                self.get_logger().error(f'supervisor: {exc!r}', throttle_duration_sec=1.0)

    def heartbeat_tick(self):
        self.client.send('heartbeat', mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                         mavlink.MAV_STATE_ACTIVE)
        if self.vehicle.status.system is not None:
            self.timesync_ts1 = time.time_ns()
            self.client.send('timesync', 0, self.timesync_ts1)
        self.publish_diagnostics()

    def set_mode(self, name, wait=True):
        s = self.vehicle.status
        main, sub = s.backend.mode_params(name)
        return self.client.command_long(s.system, self.params['target_component'], mavlink.MAV_CMD_DO_SET_MODE,
                                        [MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub],
                                        self.params['command_timeout_s'] if wait else None)

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
        with self.vehicle.lock:
            self.streams.reset(self.now_s())
        for group in s.backend.telemetry:
            self.request_messages(self.streams.current(group.name), self.group_rate_hz(group.name))
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
            answers = self.client.read_params(s.system, self.params['target_component'], s.backend.semantic_params,
                                              self.params['command_timeout_s'])
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
        if s.system is None or s.backend is None:
            response.success, response.message = False, 'no vehicle heartbeat yet'
            return False
        if self.link.state != LinkState.UP:
            response.success, response.message = False, f'link {self.link.state}'
            return False
        return True

    @staticmethod
    def _answer(response, what, result):
        response.success = result == mavlink.MAV_RESULT_ACCEPTED
        response.message = f'{what}: {result_name(result)}'
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
        result = self.client.command_long(self.vehicle.status.system, self.params['target_component'],
                                          mavlink.MAV_CMD_COMPONENT_ARM_DISARM, [1.0 if request.data else 0.0],
                                          self.params['command_timeout_s'])
        return self._answer(response, 'arm' if request.data else 'disarm', result)

    def srv_offboard(self, request, response):
        if not self._ready(response):
            return response
        backend = self.vehicle.status.backend
        if not request.data:
            with self.vehicle.lock:
                self.vehicle.handover.end('offboard false')
            mode = backend.hold_mode('hold')
            return self._answer(response, f'mode {mode}', self.set_mode(mode))
        check = self.param_check
        if check is None or (check.problems and self.params['vehicle_params'] != 'ignore'):
            check = self.read_vehicle_params()  # maybe changed on the vehicle since
        if check.problems:
            return self._refuse(response, 'offboard refused: ' + '; '.join(check.problems))
        if not self.streamer.fresh():
            return self._refuse(response, 'no live setpoint stream: publish cmd/attitude_thrust first')
        target = backend.offboard_mode
        with self.vehicle.lock:
            self.vehicle.handover.request(target, backend.prestream, self.now_s())
        self.geofence.reset()
        self.streamer.kick()
        if backend.prestream:
            deadline = time.monotonic() + PRESTREAM_WAIT_S
            while self.streamer.rate_hz() < OFFBOARD_MIN_STREAM_HZ and time.monotonic() < deadline:
                time.sleep(0.02)
            if self.streamer.rate_hz() < OFFBOARD_MIN_STREAM_HZ:
                with self.vehicle.lock:
                    self.vehicle.handover.end('the pre-stream did not reach '
                                              f'{OFFBOARD_MIN_STREAM_HZ} Hz')
                return self._refuse(response, f'no live setpoint stream: {self.streamer.rate_hz():.1f} Hz sent')
        result = self.set_mode(target)
        with self.vehicle.lock:
            self.vehicle.handover.acknowledged(result == mavlink.MAV_RESULT_ACCEPTED, result_name(result),
                                               self.now_s())
        self.streamer.kick()
        self.publish_diagnostics()
        return self._answer(response, f'mode {target}', result)

    def srv_land(self, request, response):
        if not self._ready(response):
            return response
        with self.vehicle.lock:
            self.vehicle.handover.end('land')
        mode = self.vehicle.status.backend.land_mode
        return self._answer(response, f'mode {mode}', self.set_mode(mode))

    # --- vehicle -> ROS (receive thread: decodes and publishes itself, never waits on the executor) ----

    def on_mavlink(self, msg):
        kind = msg.get_type()
        if kind == 'HEARTBEAT':
            self.on_heartbeat(msg)
            return
        s = self.vehicle.status
        if msg.get_srcSystem() != s.system or s.backend is None:
            return  # only our vehicle's telemetry is used
        handler = self.handlers.get(kind)
        if handler is None:
            return
        arrival_ns = time.time_ns()
        t_us = time_us(msg) if kind in TIMESTAMPED else None
        if t_us:
            self.clock.observe(t_us, arrival_ns)
        if self.streams is not None:
            self.streams.arrived(kind, self.now_s())
        handler(msg, self.clock.to_local_ns(t_us, arrival_ns) if t_us else arrival_ns)

    def on_heartbeat(self, msg):
        s = self.vehicle.status
        if not is_vehicle_heartbeat(msg.type, msg.autopilot):
            return
        with self.vehicle.lock:
            if s.system is None:
                s.system = msg.get_srcSystem()
            if msg.get_srcSystem() != s.system or msg.get_srcComponent() != self.params['target_component']:
                return
            if s.backend is None:
                try:
                    s.backend = backend_for(resolve_autopilot(self.params['autopilot'], msg.autopilot))
                except ValueError as exc:
                    self.get_logger().error(str(exc), throttle_duration_sec=5.0)
                    return
                self.streams = StreamSelector(s.backend.telemetry, self.params['stream_grace_s'])
            change, ended = self.vehicle.heartbeat(msg.custom_mode, bool(msg.base_mode & MAV_MODE_FLAG_SAFETY_ARMED),
                                                   self.now_s())
        event = self.link.heartbeat(self.now_s())
        if change:
            self.get_logger().info(f'vehicle mode {change}')
        if ended:
            self.get_logger().warn(ended)
            self.publish_diagnostics()
        if event:
            self.get_logger().info(f'vehicle {s.system} {event}: {s.backend.name}, mode {s.mode}')
            threading.Thread(target=self.on_connect, name='on-connect', daemon=True).start()

    def on_attitude_quaternion(self, msg, stamp_ns):
        with self.vehicle.lock:
            self.vehicle.status.q_ned = frames.from_mavlink_quaternion([msg.q1, msg.q2, msg.q3, msg.q4])
            self.vehicle.status.rates_frd = np.array([msg.rollspeed, msg.pitchspeed, msg.yawspeed])

    def on_local_position_ned(self, msg, stamp_ns):
        with self.vehicle.lock:
            q, rates = self.vehicle.status.q_ned, self.vehicle.status.rates_frd
        if self.streams.uses('odometry', 'LOCAL_POSITION_NED') and q is not None:
            self.publish_state(state_from_local_position(msg, q, rates), stamp_ns)

    def on_odometry(self, msg, stamp_ns):
        if self.streams.uses('odometry', 'ODOMETRY'):
            state = state_from_odometry(msg)
            if state is not None:
                self.publish_state(state, stamp_ns)

    def publish_state(self, state, stamp_ns):
        if not state.is_finite():
            return
        with self.vehicle.lock:
            self.vehicle.status.state = state
            armed = self.vehicle.status.armed
        self.odom_pub.publish(self.odom_packer.pack(state, stamp_ns))  # serialized: ~10x cheaper than Odometry()
        if self.geofence.check(state.position, armed):
            with self.vehicle.lock:
                self.vehicle.handover.end('geofence left')
            self.get_logger().error(f'geofence left at {np.round(state.position, 2).tolist()}: streaming stopped, '
                                    'landing')
            self.set_mode(self.vehicle.status.backend.land_mode, wait=False)

    def on_imu(self, msg, stamp_ns):
        if not self.streams.uses('imu', msg.get_type()):
            return
        acc, gyro = imu_flu(msg)
        imu = Imu()
        imu.header.stamp = _stamp(stamp_ns)
        imu.header.frame_id = conversions.BODY_FRAME
        state = self.vehicle.status.state
        if state is not None:
            imu.orientation = conversions.to_quaternion(state.quaternion)
        else:
            imu.orientation_covariance[0] = -1.0
        imu.angular_velocity = conversions.to_vector3(gyro)
        imu.linear_acceleration = conversions.to_vector3(acc)
        self.imu_pub.publish(imu)

    def on_sys_status(self, msg, stamp_ns):
        s = self.vehicle.status
        with self.vehicle.lock:
            s.prearm_ready = s.backend.prearm_ready(msg.onboard_control_sensors_present,
                                                    msg.onboard_control_sensors_enabled,
                                                    msg.onboard_control_sensors_health)
        if msg.voltage_battery != 0xFFFF:
            self.publish_battery(stamp_ns, msg.voltage_battery / 1000.0, msg.current_battery / 100.0,
                                 msg.battery_remaining)

    def on_battery_status(self, msg, stamp_ns):
        cells = [c for c in msg.voltages if c != 0xFFFF]
        self.publish_battery(stamp_ns, sum(cells) / 1000.0 if cells else float('nan'), msg.current_battery / 100.0,
                             msg.battery_remaining, [c / 1000.0 for c in cells])

    def publish_battery(self, stamp_ns, voltage_v, current_a, remaining_pct, cells_v=()):
        b = BatteryState()
        b.header.stamp = _stamp(stamp_ns)
        b.voltage = float(voltage_v)
        b.current = -float(current_a) if current_a >= 0 else float('nan')  # ROS: negative = discharging
        b.percentage = remaining_pct / 100.0 if remaining_pct >= 0 else float('nan')
        b.cell_voltage = list(map(float, cells_v))
        b.present = True
        b.power_supply_technology = BatteryState.POWER_SUPPLY_TECHNOLOGY_LIPO
        self.battery_pub.publish(b)

    def on_timesync(self, msg, arrival_ns):
        if msg.tc1 == 0:  # a request from the vehicle: answer it
            self.client.send('timesync', time.time_ns(), msg.ts1)
        elif msg.ts1 == self.timesync_ts1:
            self.clock.timesync(msg.ts1, msg.tc1, arrival_ns)
            with self.vehicle.lock:
                self.vehicle.status.rtt_ms = (arrival_ns - msg.ts1) / 1e6

    def on_statustext(self, msg, stamp_ns):
        self.get_logger().info(f'vehicle: {msg.text}')

    # --- diagnostics -------------------------------------------------------------------------------

    def publish_diagnostics(self):
        now = self.now_s()
        with self.vehicle.lock:
            s, h = self.vehicle.snapshot(), self.vehicle.handover
            phase, target, reason, ended = h.phase, h.target or '', h.reason, h.ended
            streams = self.streams
            odom_source = '+'.join(streams.current('odometry')) if streams else ''
            imu_source = '+'.join(streams.current('imu')) if streams else ''
            missing = streams.missing(now) if streams else []
            fallbacks = list(streams.notes) if streams else []
            check = self.param_check
        level = {LinkState.UP: diagnostics.OK, LinkState.WAITING: diagnostics.WARN}.get(self.link.state,
                                                                                        diagnostics.ERROR)
        if level == diagnostics.OK and (missing or (check and check.problems)):
            level = diagnostics.WARN
        link = diagnostics.status(f'{NAME}: link', level, f'link {self.link.state}', {
            'target_system': s.system, 'autopilot': s.backend.name if s.backend else '?', 'mode': s.mode,
            'armed': s.armed, 'prearm_ready': '' if s.prearm_ready is None else s.prearm_ready,
            'rtt_ms': f'{s.rtt_ms:.2f}', 'clock': self.clock.source,
            'clock_offset_jitter_ms': f'{self.clock.jitter_ms():.3f}', 'odometry_source': odom_source,
            'imu_source': imu_source, 'missing_streams': ','.join(missing), 'stream_fallbacks': '; '.join(fallbacks),
            'vehicle_params': ', '.join(f'{k}={v:g}' for k, v in sorted(s.params.items())),
            'param_problems': '; '.join(check.problems) if check else '',
            'param_notes': '; '.join(check.notes) if check else '',
            'packet_loss_pct': f'{self.client.packet_loss_pct():.2f}', 'losses': self.link.losses,
            'reconnects': self.link.reconnects, 'bad_data': self.client.bad_data,
            'handler_errors': self.client.handler_errors})
        st = self.streamer
        with self.counts_lock:
            counts = {'refused': self.refused, 'clamped': self.clamped, 'clamp_vertical_not_kept': self.clamp_short,
                      'stale_events': self.stale_events}
        sp_level = diagnostics.WARN if self.stale_events or self.geofence.breached else diagnostics.OK
        setpoints = diagnostics.status(f'{NAME}: setpoints', sp_level, reason, {
            'handover': phase, 'target_mode': target, 'handovers_ended': ended,
            'streaming': phase != 'idle' and self.may_stream(), 'rate_hz': f'{st.rate_hz():.1f}',
            'received': st.received, 'sent': st.sent_total, 'keepalives': st.keepalives,
            'superseded': st.superseded, **counts,
            'geofence_breached': self.geofence.breached})
        self.diag_pub.publish(diagnostics.array(_stamp(time.time_ns()), [link, setpoints]))

    def destroy_node(self):
        self.stopping.set()
        self.streamer.stop()
        self.supervisor.join(timeout=2.0)
        self.client.close()
        self.setpoint_thread.join(timeout=2.0)
        self.setpoint_executor.shutdown()
        self.setpoint_node.destroy_node()
        super().destroy_node()


# GIL hand-over interval: the keep-alive thread must get the interpreter within ~1 ms of its deadline, not the
# default 5 ms, while the receive thread and the executors run.
GIL_SWITCH_INTERVAL_S = 0.001


def main(args=None):
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    run_node(NAME, MavlinkBridge, refused=(ValueError, OSError), args=args)


if __name__ == '__main__':
    main()
