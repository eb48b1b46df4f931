"""The telemetry half of mavlink_bridge (rclpy): runs in the MAVLink receive thread, decodes the vehicle's
messages and publishes `odom`, `imu` and `battery` stamped with the autopilot's own time, without ever waiting
for the node's executors. Which messages are used: quad_bridge.telemetry_streams; time mapping: quad_bridge.clock."""

import time
from collections import deque

import numpy as np
from builtin_interfaces.msg import Time
from nav_msgs.msg import Odometry
from sensor_msgs.msg import BatteryState, Imu

from quad_bridge.clock import ClockMapper, answer_clock_ns
from quad_bridge.telemetry import (
    attitude_enu,
    finite,
    imu_flu_floats,
    local_position_enu,
    state_from_odometry,
    time_us,
)
from quad_bridge.telemetry_streams import StreamSelector
from quad_common import contract, rotations
from quad_common.ros import cdr
from quad_common.ros.rcl_serialized import SerializedPublisher
from quad_common.types import State

ODOM_GAP_WINDOW_S = 10.0   # diagnostics' odom_gap_max_ms: the longest gap between odometry publications this recent
TIMESTAMPED = ('ATTITUDE_QUATERNION', 'LOCAL_POSITION_NED', 'ODOMETRY', 'HIGHRES_IMU', 'SCALED_IMU', 'RAW_IMU')
# message kind -> its handler: the kinds the bridge decodes (with HEARTBEAT; the link decodes no other)
HANDLERS = {'ATTITUDE_QUATERNION': 'on_attitude_quaternion', 'LOCAL_POSITION_NED': 'on_local_position_ned',
            'ODOMETRY': 'on_odometry', 'HIGHRES_IMU': 'on_imu', 'SCALED_IMU': 'on_imu', 'RAW_IMU': 'on_imu',
            'SYS_STATUS': 'on_sys_status', 'BATTERY_STATUS': 'on_battery_status', 'TIMESYNC': 'on_timesync',
            'STATUSTEXT': 'on_statustext'}


def stamp(ns: int) -> Time:
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


class OdometryFloats(cdr.OdometryPacker):
    """cdr.OdometryPacker's bytes from Python floats (position, quaternion, body velocity, body rates), the
    layout it holds: LOCAL_POSITION_NED's odometry without a State's arrays between (every
    odometry message goes through here)."""

    def pack_floats(self, position, quaternion, v_body, rates, time_ns: int) -> bytes:
        return self._struct.pack(cdr.CDR_LE, time_ns // 1_000_000_000, time_ns % 1_000_000_000, self._frames,
                                 *position, *quaternion, *v_body, *rates)


class TelemetryPublisher:
    def __init__(self, node, vehicle, client, on_state, grace_s: float):
        """on_state(state): every published odometry state (ENU/FLU), e.g. for the geofence."""
        self.vehicle, self.client, self.on_state, self.grace_s = vehicle, client, on_state, grace_s
        c = contract
        # every DDS write with the interpreter lock released: a write that blocks holds this thread, not the others
        self.odom_pub = SerializedPublisher(node.create_publisher(Odometry, c.ODOM, c.qos(c.ODOM)))
        self.imu_pub = SerializedPublisher(node.create_publisher(Imu, c.IMU, c.qos(c.IMU)))
        self.battery_pub = SerializedPublisher(node.create_publisher(BatteryState, c.BATTERY, c.qos(c.BATTERY)))
        self.log = node.get_logger()
        self.clock = ClockMapper()
        self.streams = None            # StreamSelector once the backend is known
        self.odom_packer = OdometryFloats()   # serialized: ~10x cheaper than building the messages
        self.imu_packer = cdr.ImuPacker()
        self.timesync_ts1 = None
        self.timesync_requests_answered = 0   # PX4 maps a companion's stamps only after 500 of them (Timesync)
        self.attitude = None           # the latest ATTITUDE_QUATERNION: (quaternion ENU/FLU, body rates FLU), floats
        self.quaternion = None         # the latest published odometry's quaternion (floats), for `imu`
        self.last_odom_s = None        # monotonic time of the newest odometry publication (None: none since up)
        self.odom_gaps = deque()       # (monotonic time, time since the previous publication) over ODOM_GAP_WINDOW_S
        self.handlers = {kind: getattr(self, name) for kind, name in HANDLERS.items()}

    def start(self, backend):
        self.streams = StreamSelector(backend.telemetry, self.grace_s)

    def link_up(self):
        """The link came up (again): the time without a link is not an odometry gap of ours."""
        with self.vehicle.lock:
            self.last_odom_s = None

    def send_timesync(self):
        self.timesync_ts1 = time.time_ns()
        self.client.send('timesync', 0, self.timesync_ts1)

    def handle(self, msg, now_s: float):
        """One message of our vehicle (receive thread), with when its bytes arrived (the client's arrival_ns: on
        UDP the kernel's receive time, whatever the thread waited since)."""
        kind = msg.get_type()
        handler = self.handlers.get(kind)
        if handler is None or self.streams is None:
            return
        arrival_ns = self.client.arrival_ns or time.time_ns()
        t_us = time_us(msg) if kind in TIMESTAMPED else None
        if t_us:
            self.clock.observe(t_us, arrival_ns)
        with self.vehicle.lock:   # the supervisor reads what arrived (StreamSelector: the caller serialises)
            self.streams.arrived(kind, now_s)
        handler(msg, self.clock.to_local_ns(t_us, arrival_ns, kind) if t_us else arrival_ns)

    def info(self, now_s: float) -> dict:
        """Diagnostics values: which clock and messages are used, what never arrived."""
        st = self.streams
        return {'clock': self.clock.source, 'clock_switches': self.clock.switches,
                'clock_offset_jitter_ms': f'{self.clock.jitter_ms():.3f}',
                'clock_drift_ppm': f'{self.clock.drift_ppm():.0f}',
                'timesync_requests_answered': self.timesync_requests_answered,
                'odometry_source': '+'.join(st.current('odometry')) if st else '',
                'imu_source': '+'.join(st.current('imu')) if st else '',
                'missing_streams': ','.join(st.missing(now_s)) if st else '',
                'odom_gap_max_ms': f'{1e3 * self.odom_gap_max_s(time.monotonic() - ODOM_GAP_WINDOW_S):.1f}',
                'stream_fallbacks': '; '.join(st.notes) if st else ''}

    def odom_gap_max_s(self, since_s: float) -> float:
        """The longest time between two odometry publications that ended at or after `since_s` (monotonic),
        0 if none: what the controller's odom_timeout_s must exceed."""
        with self.vehicle.lock:
            return max((gap for t, gap in self.odom_gaps if t >= since_s), default=0.0)

    def on_attitude_quaternion(self, msg, stamp_ns):
        self.attitude = attitude_enu(msg)   # read by this thread only (on_local_position_ned)

    def on_local_position_ned(self, msg, stamp_ns):
        """LOCAL_POSITION_NED + the latest ATTITUDE_QUATERNION -> `odom`, on Python floats (the arithmetic of
        telemetry.state_from_local_position and conversions.body_velocity)."""
        if self.attitude is None or not self.streams.uses('odometry', 'LOCAL_POSITION_NED'):
            return
        (q, rates), (p, v) = self.attitude, local_position_enu(msg)
        if not finite(p, v, q, rates):
            return
        state = State(position=np.array(p), velocity=np.array(v), quaternion=np.array(q), body_rates=np.array(rates))
        self._published(state, q, self.odom_packer.pack_floats(p, q, rotations.rotate_back(q, v), rates, stamp_ns))

    def on_odometry(self, msg, stamp_ns):
        if self.streams.uses('odometry', 'ODOMETRY'):
            state = state_from_odometry(msg)
            if state is not None:
                self.publish_state(state, stamp_ns)

    def publish_state(self, state, stamp_ns):
        if state.is_finite():
            self._published(state, tuple(state.quaternion.tolist()), self.odom_packer.pack(state, stamp_ns))

    def _published(self, state, quaternion, odometry: bytes):
        """Publishes a serialized `odom` of `state` (~10x cheaper than an Odometry()); the gap bookkeeping."""
        now_s = time.monotonic()
        with self.vehicle.lock:
            self.vehicle.status.state = state
            self.quaternion = quaternion
            if self.last_odom_s is not None:
                self.odom_gaps.append((now_s, now_s - self.last_odom_s))
                while self.odom_gaps[0][0] < now_s - ODOM_GAP_WINDOW_S:
                    self.odom_gaps.popleft()
            self.last_odom_s = now_s
        self.odom_pub.publish(odometry)
        self.on_state(state)

    def on_imu(self, msg, stamp_ns):
        if not self.streams.uses('imu', msg.get_type()):
            return
        acc, gyro = imu_flu_floats(msg)
        self.imu_pub.publish(self.imu_packer.pack(self.quaternion, gyro, acc, stamp_ns))

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
        b.header.stamp = stamp(stamp_ns)
        b.voltage = float(voltage_v)
        b.current = -float(current_a) if current_a >= 0 else float('nan')  # ROS: negative = discharging
        b.percentage = remaining_pct / 100.0 if remaining_pct >= 0 else float('nan')
        b.cell_voltage = list(map(float, cells_v))
        b.present = True
        b.power_supply_technology = BatteryState.POWER_SUPPLY_TECHNOLOGY_LIPO
        self.battery_pub.publish(b)

    def on_timesync(self, msg, arrival_ns):
        if msg.tc1 == 0:  # a request from the vehicle: answer it
            self.client.send('timesync', answer_clock_ns(), msg.ts1)
            self.timesync_requests_answered += 1
        elif msg.ts1 == self.timesync_ts1:
            self.clock.timesync(msg.ts1, msg.tc1, arrival_ns)
            with self.vehicle.lock:
                self.vehicle.status.rtt_ms = (arrival_ns - msg.ts1) / 1e6

    def on_statustext(self, msg, arrival_ns):
        text = self.vehicle.texts.add(arrival_ns, msg.severity, msg.text, getattr(msg, 'id', 0),
                                      getattr(msg, 'chunk_seq', 0))
        if text is not None:   # once per text, its chunks joined
            self.log.info(f'vehicle: {text}')
