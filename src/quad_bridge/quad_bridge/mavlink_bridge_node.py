"""mavlink_bridge: `cmd/attitude_thrust` -> SET_ATTITUDE_TARGET for PX4 / ArduPilot, telemetry -> ROS.

Threads: pymavlink's receive loop runs in its own thread (quad_bridge.mavlink_client) and publishes
telemetry; timers and subscriptions run in a multi-threaded executor and only ever send (under the
client's lock) or wait on an event, never read the socket. docs/bridge.md describes it all.
"""

import math
import sys
import threading
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from sensor_msgs.msg import BatteryState, Imu
from std_srvs.srv import SetBool, Trigger

from quad_bridge import autopilot as ap
from quad_bridge import frames
from quad_bridge.link import LinkState, RateMeter, is_vehicle_heartbeat, load_signing_key, resolve_autopilot
from quad_bridge.mavlink_client import MAV_COMP_ID_ONBOARD_COMPUTER, MavlinkClient, check_fcu_url, mavlink, result_name
from quad_bridge.setpoint import check_setpoint
from quad_common import conversions, diagnostics, rotations
from quad_common.node_main import run_node
from quad_common.params import Param, ParameterSet
from quad_common.types import State

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
    Param('setpoint_rate_hz', 50.0, 'SET_ATTITUDE_TARGET rate (newest valid setpoint re-sent)', min=2.0, max=1000.0,
          read_only=True),
    Param('setpoint_timeout_s', 0.5, 'no new setpoint for this long: stop streaming, command stale_action',
          min=0.02, max=10.0),
    Param('stale_action', 'land', 'what a stale setpoint stream commands: land | hold (ArduPilot always lands)',
          choices=('land', 'hold')),
    Param('link_timeout_s', 2.0, 'no vehicle heartbeat for this long: link lost', min=0.2, max=30.0),
    Param('hover_throttle', 0.5,
          'normalised thrust that hovers the vehicle (PX4 MPC_THR_HOVER, ArduPilot MOT_THST_HOVER)',
          min=0.05, max=0.95),
    Param('max_tilt_deg', 35.0, 'setpoints tilted further are clamped to this (and counted)', min=1.0, max=85.0),
    Param('ardupilot_thrust_mode', 'thrust', 'thrust (GUID_OPTIONS bit 3 set) | climb_rate (bit 3 clear)',
          choices=('thrust', 'climb_rate')),
    Param('ardupilot_speed_up_mps', 2.5, 'WPNAV_SPEED_UP: climb rate at thrust 1 (climb_rate mode)', min=0.1, max=20.0),
    Param('ardupilot_speed_down_mps', 1.5, 'WPNAV_SPEED_DN: descent rate at thrust 0 (climb_rate mode)',
          min=0.1, max=20.0),
    Param('climb_rate_lead_s', 0.5, 'climb_rate mode: v_z command = v_z + lead * (f cos(tilt) - g)', min=0.01, max=5.0),
    Param('telemetry_rate_hz', 50.0, 'rate requested with MAV_CMD_SET_MESSAGE_INTERVAL for odometry/IMU',
          min=1.0, max=500.0, read_only=True),
    Param('command_timeout_s', 3.0, 'how long a service waits for COMMAND_ACK', min=0.1, max=30.0),
    Param('geofence_enabled', False, 'land when the vehicle leaves the box geofence_min_m..geofence_max_m (ENU)'),
    Param('geofence_min_m', [-50.0, -50.0, -1.0], 'geofence box lower corner (map, ENU)', length=3),
    Param('geofence_max_m', [50.0, 50.0, 30.0], 'geofence box upper corner (map, ENU)', length=3),
    Param('signing_key_file', '', 'MAVLink 2 signing key file (64 hex chars or a passphrase); empty = unsigned',
          read_only=True),
]
TELEMETRY_MESSAGES = {  # message id -> share of telemetry_rate_hz
    mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 1.0,
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 1.0,
    mavlink.MAVLINK_MSG_ID_HIGHRES_IMU: 1.0,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: 0.0,       # 0: 2 Hz
    mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: 0.0,
}
OFFBOARD_MIN_STREAM_HZ = 5.0  # sent before asking for OFFBOARD (PX4 needs >= 2 Hz)
ATTITUDE_RATES_IGNORE = (mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE
                         | mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE
                         | mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_YAW_RATE_IGNORE)


def _validate(values):
    reason = check_fcu_url(values['fcu_url'])
    if reason:
        raise ValueError(reason)
    if any(lo >= hi for lo, hi in zip(values['geofence_min_m'], values['geofence_max_m'])):
        raise ValueError(f'geofence_min_m = {values["geofence_min_m"]} must be below geofence_max_m = '
                         f'{values["geofence_max_m"]} on every axis')


class VehicleStatus:
    """What we know about the target vehicle (written by the receive thread)."""

    def __init__(self):
        self.system = None
        self.component = None
        self.autopilot = None
        self.custom_mode = 0
        self.armed = False
        self.prearm_ready = False
        self.q_ned = None
        self.rates_frd = np.zeros(3)
        self.state = None          # latest State in ENU/FLU
        self.rtt_ms = float('nan')


class MavlinkBridge(Node):
    def __init__(self):
        super().__init__(NAME)
        self.params = ParameterSet(self, PARAMS, validate=_validate)
        p = self.params
        key = load_signing_key(p['signing_key_file']) if p['signing_key_file'] else None
        self.vehicle = VehicleStatus()
        if p['target_system']:
            self.vehicle.system = p['target_system']
        self.link = LinkState(p['link_timeout_s'])
        self.sent = RateMeter()
        self.t0 = time.monotonic()
        self.lock = threading.Lock()  # guards the setpoint fields below
        self.setpoint = None
        self.setpoint_time_s = -math.inf
        self.streaming = False
        self.fence_breached = False
        self.refused = self.clamped = self.stale_events = 0
        self.timesync_ts1 = None
        self.handlers = {'ATTITUDE_QUATERNION': self.on_attitude_quaternion,
                         'LOCAL_POSITION_NED': self.on_local_position_ned, 'ODOMETRY': self.on_odometry,
                         'HIGHRES_IMU': self.on_highres_imu, 'SYS_STATUS': self.on_sys_status,
                         'BATTERY_STATUS': self.on_battery_status, 'TIMESYNC': self.on_timesync,
                         'STATUSTEXT': self.on_statustext}

        qos = 10
        self.odom_pub = self.create_publisher(Odometry, 'odom', qos)
        self.imu_pub = self.create_publisher(Imu, 'imu', qos)
        self.battery_pub = self.create_publisher(BatteryState, 'battery', qos)
        self.diag_pub = self.create_publisher(DiagnosticArray, 'diagnostics', qos)
        self.create_subscription(Imu, 'cmd/attitude_thrust', self.on_setpoint, qos)
        services = ReentrantCallbackGroup()
        self.create_service(SetBool, 'arm', self.srv_arm, callback_group=services)
        self.create_service(SetBool, 'offboard', self.srv_offboard, callback_group=services)
        self.create_service(Trigger, 'land', self.srv_land, callback_group=services)

        self.client = MavlinkClient(p['fcu_url'], p['source_system'], p['source_component'], self.on_mavlink,
                                    baud=p['baud'], signing_key=key)
        timers = MutuallyExclusiveCallbackGroup()
        self.create_timer(1.0, self.heartbeat_tick, callback_group=timers)
        self.create_timer(0.05, self.link_tick, callback_group=timers)
        self.client.start()
        self.stopping = threading.Event()
        self.stream_thread = threading.Thread(target=self.stream_loop, name='setpoint-stream', daemon=True)
        self.stream_thread.start()
        self.get_logger().info(f'{NAME}: {p["fcu_url"]}, autopilot {p["autopilot"]}, '
                               f'setpoints at {p["setpoint_rate_hz"]} Hz')

    def now_s(self) -> float:
        return time.monotonic() - self.t0

    # --- ROS -> vehicle -------------------------------------------------------------------------

    def on_setpoint(self, msg: Imu):
        try:
            sp, clamped = check_setpoint(conversions.imu_to_setpoint(msg), math.radians(self.params['max_tilt_deg']))
        except ValueError as exc:
            self.refused += 1
            self.get_logger().warn(f'setpoint refused ({self.refused} so far): {exc}', throttle_duration_sec=1.0)
            return
        if clamped:
            self.clamped += 1
            self.get_logger().warn(f'setpoint tilt clamped to {self.params["max_tilt_deg"]} deg '
                                   f'({self.clamped} so far)', throttle_duration_sec=1.0)
        with self.lock:
            self.setpoint, self.setpoint_time_s = sp, self.now_s()

    def stream_loop(self):
        """stream_tick at setpoint_rate_hz in a thread of its own: a fixed rate that executor load cannot
        stretch (rclpy timers share the executor with the subscription and the services); when late it
        skips ahead instead of bursting."""
        period_s = 1.0 / self.params['setpoint_rate_hz']
        next_s = time.monotonic()
        while not self.stopping.is_set():
            try:
                self.stream_tick()
            except Exception as exc:  # never let the stream thread die silently
                self.get_logger().error(f'setpoint stream: {exc!r}', throttle_duration_sec=1.0)
            next_s += period_s
            delay_s = next_s - time.monotonic()
            if delay_s < -period_s:
                next_s = time.monotonic()
            elif delay_s > 0:
                self.stopping.wait(delay_s)

    def stream_tick(self):
        """Re-send the newest valid setpoint; a stale stream stops and lands/holds the vehicle once."""
        v = self.vehicle
        with self.lock:
            sp, fresh = self.setpoint, self.now_s() - self.setpoint_time_s <= self.params['setpoint_timeout_s']
            if self.streaming and not fresh:
                self.streaming = False
                self.stale_events += 1
                stale = True
            else:
                stale = False
                self.streaming = fresh and sp is not None
        if stale:
            in_offboard = v.autopilot and ap.mode_name(v.autopilot, v.custom_mode) == ap.offboard_mode(v.autopilot)
            action = 'nothing commanded (vehicle not flying our setpoints)'
            if v.armed and in_offboard and self.link.state == LinkState.UP:
                mode = ap.land_mode(v.autopilot) if self.params['stale_action'] == 'land' else ap.hold_mode(v.autopilot)
                self.set_mode(mode, wait=False)
                action = f'commanding {mode}'
            self.get_logger().error(f'setpoints stale (none for {self.params["setpoint_timeout_s"]} s): '
                                    f'streaming stopped, {action}')
            return
        if not self.streaming or v.autopilot is None or self.link.state != LinkState.UP or self.fence_breached:
            return
        self.client.send('set_attitude_target', int(self.now_s() * 1000) & 0xFFFFFFFF, v.system,
                         self.params['target_component'], *self.attitude_target(sp))
        self.sent.tick(self.now_s())

    def attitude_target(self, sp):
        """(type_mask, q, roll rate, pitch rate, yaw rate, thrust) of SET_ATTITUDE_TARGET, in NED/FRD."""
        v, p = self.vehicle, self.params
        q_ned = frames.quaternion_enu_to_ned(sp.quaternion)
        if v.autopilot == ap.MAV_AUTOPILOT_PX4:
            thrust = ap.thrust_px4(sp.specific_force_mps2, p['hover_throttle'])
        elif p['ardupilot_thrust_mode'] == 'thrust':
            thrust = ap.thrust_ardupilot(sp.specific_force_mps2, p['hover_throttle'], sp.quaternion)
        else:
            vz = v.state.velocity[2] if v.state is not None else 0.0
            rate = ap.climb_rate_command(sp.specific_force_mps2, sp.quaternion, vz, p['climb_rate_lead_s'])
            thrust = ap.climb_rate_to_thrust(rate, p['ardupilot_speed_up_mps'], p['ardupilot_speed_down_mps'])
        if sp.body_rates is None:
            mask, rates = ATTITUDE_RATES_IGNORE, np.zeros(3)
        else:
            mask, rates = 0, frames.body_flu_frd(sp.body_rates)
        return (mask, frames.to_mavlink_quaternion(q_ned), *map(float, rates), thrust)

    def heartbeat_tick(self):
        self.client.send('heartbeat', mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                         mavlink.MAV_STATE_ACTIVE)
        if self.vehicle.system is not None:
            self.timesync_ts1 = time.monotonic_ns()
            self.client.send('timesync', 0, self.timesync_ts1)
        self.publish_diagnostics()

    def link_tick(self):
        if self.link.update(self.now_s()) == 'lost':
            self.get_logger().error(f'vehicle heartbeat lost (none for {self.params["link_timeout_s"]} s)')
            self.publish_diagnostics()

    def set_mode(self, name, wait=True):
        v = self.vehicle
        main, sub = ap.mode_from_name(v.autopilot, name)
        return self.client.command_long(v.system, self.params['target_component'], mavlink.MAV_CMD_DO_SET_MODE,
                                        [ap.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub],
                                        self.params['command_timeout_s'] if wait else None)

    # --- services -------------------------------------------------------------------------------

    def _ready(self, response):
        if self.vehicle.system is None or self.vehicle.autopilot is None:
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

    def srv_arm(self, request, response):
        if not self._ready(response):
            return response
        result = self.client.command_long(self.vehicle.system, self.params['target_component'],
                                          mavlink.MAV_CMD_COMPONENT_ARM_DISARM, [1.0 if request.data else 0.0],
                                          self.params['command_timeout_s'])
        return self._answer(response, 'arm' if request.data else 'disarm', result)

    def srv_offboard(self, request, response):
        if not self._ready(response):
            return response
        v = self.vehicle
        if request.data:
            deadline = time.monotonic() + 2.0  # PX4 enters OFFBOARD only with a live (>= 2 Hz) stream
            while self.sent.rate_hz(self.now_s()) < OFFBOARD_MIN_STREAM_HZ and time.monotonic() < deadline:
                time.sleep(0.05)
            if not self.streaming:
                response.success = False
                response.message = 'no live setpoint stream: publish cmd/attitude_thrust first'
                return response
            self.fence_breached = False
            mode = ap.offboard_mode(v.autopilot)
        else:
            mode = ap.hold_mode(v.autopilot)
        return self._answer(response, f'mode {mode}', self.set_mode(mode))

    def srv_land(self, request, response):
        if not self._ready(response):
            return response
        mode = ap.land_mode(self.vehicle.autopilot)
        return self._answer(response, f'mode {mode}', self.set_mode(mode))

    # --- vehicle -> ROS (receive thread) ----------------------------------------------------------

    def on_mavlink(self, msg):
        kind = msg.get_type()
        src = msg.get_srcSystem()
        v = self.vehicle
        if kind == 'HEARTBEAT':
            self.on_heartbeat(msg)
            return
        if src != v.system:
            return  # only our vehicle's telemetry is used
        handler = self.handlers.get(kind)
        if handler is not None:
            handler(msg)

    def on_heartbeat(self, msg):
        v = self.vehicle
        if not is_vehicle_heartbeat(msg.type, msg.autopilot):
            return
        if v.system is None:
            v.system = msg.get_srcSystem()
        if msg.get_srcSystem() != v.system or msg.get_srcComponent() != self.params['target_component']:
            return
        if v.autopilot is None:
            try:
                v.autopilot = resolve_autopilot(self.params['autopilot'], msg.autopilot)
            except ValueError as exc:
                self.get_logger().error(str(exc), throttle_duration_sec=5.0)
                return
        v.custom_mode = msg.custom_mode
        v.armed = bool(msg.base_mode & ap.MAV_MODE_FLAG_SAFETY_ARMED)
        event = self.link.heartbeat(self.now_s())
        if event:
            self.get_logger().info(f'vehicle {v.system} {event}: {self.autopilot_name()}, '
                                   f'mode {ap.mode_name(v.autopilot, v.custom_mode)}')
            self.request_telemetry()

    def autopilot_name(self):
        names = {ap.MAV_AUTOPILOT_PX4: 'PX4', ap.MAV_AUTOPILOT_ARDUPILOTMEGA: 'ArduPilot'}
        return names.get(self.vehicle.autopilot, '?')

    def request_telemetry(self):
        rate_hz = self.params['telemetry_rate_hz']
        for msg_id, share in TELEMETRY_MESSAGES.items():
            interval_us = 1e6 / (rate_hz * share) if share else 5e5
            self.client.command_long(self.vehicle.system, self.params['target_component'],
                                     mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, [msg_id, interval_us])

    def on_attitude_quaternion(self, msg):
        self.vehicle.q_ned = frames.from_mavlink_quaternion([msg.q1, msg.q2, msg.q3, msg.q4])
        self.vehicle.rates_frd = np.array([msg.rollspeed, msg.pitchspeed, msg.yawspeed])

    def on_local_position_ned(self, msg):
        v = self.vehicle
        if v.q_ned is None:
            return
        self.publish_state(State(position=np.array([msg.x, msg.y, msg.z]), velocity=np.array([msg.vx, msg.vy, msg.vz]),
                                 quaternion=v.q_ned, body_rates=v.rates_frd))

    def on_odometry(self, msg):
        """ODOMETRY with a NED world frame; velocity in body FRD (child frame) or in the world frame."""
        if msg.frame_id not in (mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_LOCAL_FRD):
            return
        q = frames.from_mavlink_quaternion(msg.q)
        vel = np.array([msg.vx, msg.vy, msg.vz])
        if msg.child_frame_id == mavlink.MAV_FRAME_BODY_FRD:
            vel = rotations.to_matrix(q) @ vel
        self.publish_state(State(position=np.array([msg.x, msg.y, msg.z]), velocity=vel, quaternion=q,
                                 body_rates=np.array([msg.rollspeed, msg.pitchspeed, msg.yawspeed])))

    def publish_state(self, state_ned: State):
        state = frames.state_from_ned(state_ned)
        if not state.is_finite():
            return
        self.vehicle.state = state
        self.odom_pub.publish(conversions.state_to_odometry(state, self.get_clock().now().to_msg()))
        self.check_geofence(state.position)

    def check_geofence(self, position):
        p = self.params
        if not p['geofence_enabled'] or self.fence_breached or not self.vehicle.armed:
            return
        if np.all(position >= p['geofence_min_m']) and np.all(position <= p['geofence_max_m']):
            return
        self.fence_breached = True
        self.get_logger().error(f'geofence left at {np.round(position, 2).tolist()}: streaming stopped, landing')
        self.set_mode(ap.land_mode(self.vehicle.autopilot), wait=False)

    def on_highres_imu(self, msg):
        imu = Imu()
        imu.header.stamp = self.get_clock().now().to_msg()
        imu.header.frame_id = conversions.BODY_FRAME
        if self.vehicle.state is not None:
            imu.orientation = conversions.to_quaternion(self.vehicle.state.quaternion)
        else:
            imu.orientation_covariance[0] = -1.0
        imu.angular_velocity = conversions.to_vector3(frames.body_flu_frd([msg.xgyro, msg.ygyro, msg.zgyro]))
        imu.linear_acceleration = conversions.to_vector3(frames.body_flu_frd([msg.xacc, msg.yacc, msg.zacc]))
        self.imu_pub.publish(imu)

    def on_sys_status(self, msg):
        bit = mavlink.MAV_SYS_STATUS_PREARM_CHECK
        self.vehicle.prearm_ready = bool(msg.onboard_control_sensors_present & bit
                                         and msg.onboard_control_sensors_health & bit)
        if msg.voltage_battery != 0xFFFF:
            self.publish_battery(msg.voltage_battery / 1000.0, msg.current_battery / 100.0, msg.battery_remaining)

    def on_battery_status(self, msg):
        cells = [c for c in msg.voltages if c != 0xFFFF]
        self.publish_battery(sum(cells) / 1000.0 if cells else float('nan'), msg.current_battery / 100.0,
                             msg.battery_remaining, [c / 1000.0 for c in cells])

    def publish_battery(self, voltage_v, current_a, remaining_pct, cells_v=()):
        b = BatteryState()
        b.header.stamp = self.get_clock().now().to_msg()
        b.voltage = float(voltage_v)
        b.current = -float(current_a) if current_a >= 0 else float('nan')  # ROS: negative = discharging
        b.percentage = remaining_pct / 100.0 if remaining_pct >= 0 else float('nan')
        b.cell_voltage = list(map(float, cells_v))
        b.present = True
        b.power_supply_technology = BatteryState.POWER_SUPPLY_TECHNOLOGY_LIPO
        self.battery_pub.publish(b)

    def on_timesync(self, msg):
        if msg.tc1 == 0:  # a request from the vehicle: answer it
            self.client.send('timesync', time.monotonic_ns(), msg.ts1)
        elif msg.ts1 == self.timesync_ts1:
            self.vehicle.rtt_ms = (time.monotonic_ns() - msg.ts1) / 1e6

    def on_statustext(self, msg):
        self.get_logger().info(f'vehicle: {msg.text}')

    # --- diagnostics -----------------------------------------------------------------------------

    def publish_diagnostics(self):
        v, now = self.vehicle, self.now_s()
        level = {LinkState.UP: diagnostics.OK, LinkState.WAITING: diagnostics.WARN}.get(self.link.state,
                                                                                        diagnostics.ERROR)
        link = diagnostics.status(f'{NAME}: link', level, f'link {self.link.state}', {
            'target_system': v.system, 'autopilot': self.autopilot_name(),
            'mode': ap.mode_name(v.autopilot, v.custom_mode) if v.autopilot else '', 'armed': v.armed,
            'prearm_ready': v.prearm_ready, 'rtt_ms': f'{v.rtt_ms:.2f}',
            'packet_loss_pct': f'{self.client.packet_loss_pct():.2f}', 'losses': self.link.losses,
            'reconnects': self.link.reconnects, 'bad_data': self.client.bad_data,
            'handler_errors': self.client.handler_errors})
        sp_level = diagnostics.WARN if self.stale_events or self.fence_breached else diagnostics.OK
        setpoints = diagnostics.status(f'{NAME}: setpoints', sp_level,
                                       'streaming' if self.streaming else 'not streaming', {
                                           'rate_hz': f'{self.sent.rate_hz(now):.1f}', 'refused': self.refused,
                                           'clamped': self.clamped, 'stale_events': self.stale_events,
                                           'geofence_breached': self.fence_breached})
        self.diag_pub.publish(diagnostics.array(self.get_clock().now().to_msg(), [link, setpoints]))

    def destroy_node(self):
        self.stopping.set()
        self.stream_thread.join(timeout=2.0)
        self.client.close()
        super().destroy_node()


# GIL hand-over interval: the stream thread must get the interpreter within ~1 ms of its deadline, not the default
# 5 ms, while rclpy's MultiThreadedExecutor loop spins (bench/bench_bridge.py: at 200 Hz 170-180 -> 190-193 Hz sent).
GIL_SWITCH_INTERVAL_S = 0.001


def main(args=None):
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    run_node(NAME, MavlinkBridge, refused=(ValueError, OSError),
             make_executor=lambda node: MultiThreadedExecutor(num_threads=4), args=args)


if __name__ == '__main__':
    main()
