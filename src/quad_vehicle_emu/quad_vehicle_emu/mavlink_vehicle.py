"""mavlink_vehicle: quad_sim's plant behind a real MAVLink endpoint, behaving like PX4 or ArduPilot Copter.

The protocol (modes, type_mask, thrust, parameters, streams, SYS_STATUS) is the emulator's own reading of the
autopilots' source (quad_vehicle_emu.protocol, .onboard_params, .autopilots), independent of quad_bridge. The
vehicle is quad_vehicle_emu.plant's AutopilotPlant (quad_sim's Simulator with the autopilot's quaternion attitude
loop, behind the attitude response, with the estimate fused from the received vision poses), flown in real time
here; then a telemetry delay line. Every message's time field is the vehicle's own boot clock at the sample it
carries.

    python -m quad_vehicle_emu.mavlink_vehicle --autopilot px4 --url udpout:127.0.0.1:14540

With --mocap-topic it also publishes its truth as a motion-capture system does (quad_vehicle_emu.mocap).
"""

import argparse
import math
import os
import random
import sys
import time

import numpy as np

os.environ.setdefault('MAVLINK20', '1')
from pymavlink import mavutil  # noqa: E402

from quad_common import rotations  # noqa: E402
from quad_common.realtime import apply_or_report, freeze_startup_heap  # noqa: E402
from quad_common.signing_key import load_signing_key  # noqa: E402
from quad_common.types import GRAVITY_MPS2  # noqa: E402
from quad_vehicle_emu import ned  # noqa: E402
from quad_vehicle_emu import protocol as p  # noqa: E402
from quad_vehicle_emu.attitude import DelayLine  # noqa: E402
from quad_vehicle_emu.autopilots import AttitudeTargetMsg, make_autopilot  # noqa: E402
from quad_vehicle_emu.external_vision import VisionClock  # noqa: E402
from quad_vehicle_emu.plant import add_plant_arguments, plant_from_flags  # noqa: E402

# the autopilot's own MAVLink system id parameter (PX4 mavlink_params.c, ArduCopter Parameters.cpp): read at boot
SYSTEM_ID_PARAMS = {'px4': 'MAV_SYS_ID', 'ardupilot': 'SYSID_THISMAV'}
HOME_LAT_DEG, HOME_LON_DEG, HOME_ALT_M = -35.363261, 149.165230, 584.0   # ArduPilot SITL's default (CMAC)
EARTH_RADIUS_M = 6378137.0
# ArduCopter SITL's telemetry was ~50 ms old: 35 ms here plus the wait for the next burst, uniform
# up to 40 ms apart (mean wait E[T^2] / 2E[T] = 40 / 3 ms), 48 ms on average
DEFAULT_LATENCY_S = {'px4': 0.02, 'ardupilot': 0.035}
DEFAULT_BURST_S = {'px4': 0.0, 'ardupilot': 0.04}      # ArduPilot SITL telemetry arrived 0.5-65 ms apart


class Streams:
    """Message rates and their schedule. ArduPilot sends messages that share an interval as one bucket
    (libraries/GCS_MAVLink/GCS_Common.cpp, deferred_message_bucket), so they leave together."""

    def __init__(self, defaults_hz, streamable):
        self.streamable = streamable
        self.defaults_hz = dict(defaults_hz)
        self.rates_hz = dict(defaults_hz)
        self.next_due_s = {}

    def set_rate(self, name, rate_hz):
        if rate_hz > 0:
            self.rates_hz[name] = float(rate_hz)
        else:
            self.rates_hz.pop(name, None)

    def due(self, now_s, bucketed: bool) -> list[str]:
        out = []
        keys = {}
        for name, rate in self.rates_hz.items():
            key = round(1000.0 / rate) if bucketed else name   # interval_ms groups a bucket
            keys.setdefault(key, []).append((name, rate))
        for key, members in keys.items():
            interval = 1.0 / members[0][1]
            due_s = self.next_due_s.get(key, 0.0)
            if now_s >= due_s:
                self.next_due_s[key] = max(due_s + interval, now_s - interval)
                out.extend(name for name, _ in members)
        return out


class MavlinkVehicle:
    """Socket, clocks, the autopilot's modes and telemetry around the AutopilotPlant (quad_vehicle_emu.plant)."""

    def __init__(self, args):
        self.args = args
        self.flavour = args.autopilot
        self.ap = make_autopilot(self.flavour, args.hover_throttle, dict(args.param),  # bad parameters: first
                                 rp_rates_with_attitude=args.rp_rates_with_attitude == 'fed')
        self.system_id = int(self.ap.params[SYSTEM_ID_PARAMS[self.flavour]])
        # the autopilot drops roll/pitch rates itself (make_autopilot's rp_rates_with_attitude); the truth is what
        # it believes until the loop's first tick steps the estimate
        self.plant = plant_from_flags(args, vision_timeout_s=self.ap.position_timeout_s(), estimate_now=False)
        sim = self.plant.sim
        self.vision_clock = VisionClock(self.flavour)   # when a received pose is fused (external_vision)
        self.vision_refusals = set()                     # reasons a pose was not fused, each printed once
        sim.warm_up()  # before the first heartbeat: compiling mid-flight would stall the link for seconds
        if not sim.landed:  # starts in the air: armed, holding position
            self.ap.armed = True
            self.ap.mode = 'AUTO.LOITER' if self.flavour == 'px4' else 'LOITER'
        tick_s = 1.0 / args.loop_rate_hz
        self.steps_per_tick = sim.steps_in(round(tick_s * args.physics_rate_hz) / args.physics_rate_hz)
        latency = DEFAULT_LATENCY_S[self.flavour] if args.telemetry_latency_s is None else args.telemetry_latency_s
        self.telemetry = DelayLine(latency)
        self.burst_s = DEFAULT_BURST_S[self.flavour] if args.burst_s is None else args.burst_s
        self.rng = random.Random(args.seed)
        self.queue = []              # ArduPilot: packed messages waiting for the next burst
        self.next_burst_s = 0.0
        if self.flavour == 'px4':
            self.streams = Streams(p.PX4_ONBOARD_DEFAULT_RATES_HZ, p.PX4_STREAMABLE)
        else:
            self.streams = Streams(p.COPTER_DEFAULT_RATES_HZ, p.COPTER_STREAMABLE)
        self.conn = mavutil.mavlink_connection(args.url, source_system=self.system_id, source_component=1,
                                               autoreconnect=True, robust_parsing=True)
        if args.signing_key_file:  # signs what it sends and accepts only messages signed with the same key
            self.conn.setup_signing(load_signing_key(args.signing_key_file), sign_outgoing=True)
        self.mav = self.conn.mav
        if not (math.isfinite(args.clock_rate) and 0.5 <= args.clock_rate <= 2.0):
            raise ValueError(f'--clock-rate = {args.clock_rate!r} must be a number in [0.5, 2]')
        self.t0 = time.monotonic()
        self.wall0_ns = time.time_ns()   # the wall clock at t0 (the test's truth for the boot clock)
        self.log_index = 0
        self.statustext_id = 0      # the id of the last chunked STATUSTEXT (1..65535)
        self.last_update_s = 0.0
        self._snap = None
        self.mocap = mocap_publisher(args, self.wall0_ns)   # None without --mocap-topic

    # --- clocks -----------------------------------------------------------------------------------------

    def now_s(self):
        return time.monotonic() - self.t0

    def boot_s(self, t_s):
        """The vehicle's boot clock (time_boot_ms / time_usec / TIMESYNC) at emulator time t_s: it runs at
        clock_rate of ours (PX4 SIH's ran at 0.984-0.993 of wall time, 0.93 under load)."""
        return self.args.boot_offset_s + self.args.clock_rate * t_s

    # --- loop -------------------------------------------------------------------------------------------

    def run(self):
        tick_s = 1.0 / self.args.loop_rate_hz
        while self.args.duration_s <= 0 or self.now_s() < self.args.duration_s:
            self.receive()
            self.tick(self.now_s())
            sleep_s = self.plant.sim.time_s + tick_s - self.now_s()
            if sleep_s > 0:
                time.sleep(sleep_s)

    def tick(self, now):
        """One loop tick at now (this clock, after the received messages): the autopilot's modes, physics caught
        up with now (at most 5 ticks of it after a stall), the estimate at now, telemetry."""
        sim = self.plant.sim
        self.control(now)
        lag_steps = int((now - sim.time_s) * self.args.physics_rate_hz)
        self.plant.advance_steps(min(max(lag_steps, 0), 5 * self.steps_per_tick))
        if self.mocap is not None:   # the truth, as a motion-capture system sees it
            self.mocap.offer(sim.time_s, sim.position_m, sim.state.quaternion)
        estimated = self.plant.step_estimate(now, self.ap.vision_axes())
        self.telemetry.push(now, (estimated, sim.specific_force_body_mps2.copy()))
        self.send_telemetry(now)
        self.send_log()

    def control(self, now):
        """The autopilot's modes on what it believes (the plant's estimate): its target through the attitude
        response over the time since the last tick; disarmed, the motors off and the response at rest."""
        dt = min(max(now - self.last_update_s, 0.0), 0.1)
        self.last_update_s = now
        state = self.plant.observed()
        target = self.ap.update(state, self.plant.sim.landed, now, dt)
        self.plant.sim.armed = target is not None
        if target is None:
            self.plant.rest(state.quaternion)
            return
        self.plant.command(target)
        self.plant.respond(dt)

    def receive(self):
        for _ in range(200):
            try:
                msg = self.conn.recv_match(blocking=False)
            except Exception:
                continue
            if msg is None:
                return
            kind = msg.get_type()
            if kind == 'BAD_DATA' or getattr(msg, 'target_system', self.system_id) not in (0, self.system_id):
                continue
            try:
                self.handle(msg, kind)
            except (ValueError, TypeError, OverflowError, KeyError) as exc:  # malformed fields
                print(f'mavlink_vehicle: {kind} ignored: {exc}', flush=True)

    def handle(self, msg, kind):
        now = self.now_s()
        if kind == 'SET_ATTITUDE_TARGET':
            self.ap.on_attitude_target(AttitudeTargetMsg(msg.type_mask, tuple(msg.q), (
                msg.body_roll_rate, msg.body_pitch_rate, msg.body_yaw_rate), msg.thrust,
                tuple(getattr(msg, 'thrust_body', (0.0, 0.0, 0.0)))), now)
        elif kind == 'COMMAND_LONG':
            self.on_command(msg, now)
        elif kind == 'VISION_POSITION_ESTIMATE' or (kind == 'ODOMETRY' and (
                self.flavour == 'ardupilot' or msg.estimator_type in p.PX4_VISUAL_ODOMETRY_ESTIMATORS)):
            # PX4 mavlink_receiver.cpp: VISION_POSITION_ESTIMATE and ODOMETRY from VISION / VIO go to
            # vehicle_visual_odometry (MOCAP elsewhere); ArduPilot GCS_Common.cpp hands both to AP_VisualOdom
            self.on_vision_pose(msg, kind, now)
        elif kind == 'TIMESYNC' and msg.tc1 == 0:
            # both answer with their own boot clock in ns (PX4 src/modules/mavlink/mavlink_timesync.cpp,
            # ArduPilot GCS_Common.cpp handle_timesync: tc1 = now_ns, ts1 echoed)
            self.mav.timesync_send(int(self.boot_s(now) * 1e9), msg.ts1)
        elif kind == 'TIMESYNC' and self.flavour == 'px4':
            # the answer to PX4's own request: its offset to the companion's clock (mavlink_timesync.cpp)
            self.vision_clock.timesync.update(int(self.boot_s(now) * 1e6), msg.tc1, msg.ts1)
        elif kind == 'REQUEST_DATA_STREAM' and self.flavour == 'ardupilot':
            self.on_request_data_stream(msg)
        elif kind == 'PARAM_REQUEST_READ':
            name = msg.param_id.rstrip('\x00') if isinstance(msg.param_id, str) else msg.param_id
            if msg.param_index >= 0:
                if msg.param_index < len(self.ap.params.order):
                    self.send_param(self.ap.params.order[msg.param_index])
            elif name in self.ap.params.specs:
                self.send_param(name)
        elif kind == 'PARAM_REQUEST_LIST':
            for name in self.ap.params.order:
                self.send_param(name)
        elif kind == 'PARAM_SET':
            self.on_param_set(msg, now)

    def on_vision_pose(self, msg, kind, now):
        """An external-vision pose to the estimator, as its fields say: position (NED), frame, stamp (fused at
        the instant quad_vehicle_emu.external_vision.VisionClock gives). ODOMETRY pose frames: PX4
        mavlink_receiver.cpp handle_message_odometry takes MAV_FRAME_LOCAL_NED and MAV_FRAME_LOCAL_FRD (the FRD
        frame's heading alignment to EKF2's is not emulated: its axes are taken as north, east, down);
        VISION_POSITION_ESTIMATE is local NED."""
        if kind == 'ODOMETRY':
            if msg.frame_id not in (p.MAV_FRAME_LOCAL_NED, p.MAV_FRAME_LOCAL_FRD):
                why = f'ODOMETRY frame_id {msg.frame_id} not a local NED / FRD frame: not fused'
                self._refuse_vision(why, why)
                return
            stamp_us = int(msg.time_usec)
        else:
            stamp_us = int(msg.usec)
        position_ned = np.array([msg.x, msg.y, msg.z], dtype=float)
        if not np.all(np.isfinite(position_ned)):
            self._refuse_vision(f'{kind} not finite', f'{kind} position {position_ned.tolist()} not finite: not fused')
            return
        arrival_us = int(self.boot_s(now) * 1e6)
        fusion_us = self.vision_clock.fusion_us(stamp_us, arrival_us, self.ap.vision_delay_ms())
        if fusion_us < 0:   # PX4: before boot (a stamp in another clock once TIMESYNC converged): "too fast"
            self._refuse_vision(f'{kind} stamp maps before boot', f'{kind} stamp {stamp_us} us maps to {fusion_us} '
                                'us, before boot: not fused (nor any other in that clock; shown once)')
            return
        fusion_s = (fusion_us * 1e-6 - self.args.boot_offset_s) / self.args.clock_rate
        self.plant.fuse_vision(ned.enu_to_ned(position_ned), fusion_s)   # the swap NED <-> ENU is its own inverse
        self.ap.on_external_pose(now)

    def _refuse_vision(self, key, text):
        if key not in self.vision_refusals:
            self.vision_refusals.add(key)
            print(f'mavlink_vehicle: {text}', flush=True)

    def on_command(self, msg, now):
        params = [msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7]
        if msg.command == p.MAV_CMD_SET_MESSAGE_INTERVAL:
            result = self.set_interval(int(params[0]), params[1], now)
        elif msg.command == p.MAV_CMD_REQUEST_MESSAGE:
            entry = mavutil.mavlink.mavlink_map.get(int(params[0]))
            ok = entry is not None and entry.msgname in self.streams.streamable
            if ok:
                self.send_message(entry.msgname, now)
            result = p.MAV_RESULT_ACCEPTED if ok else p.MAV_RESULT_FAILED
        else:
            result = self.ap.command(msg.command, params, self.plant.sim.landed, now)
        self.mav.command_ack_send(msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())

    def set_interval(self, msg_id, interval_us, now) -> int:
        """MAV_CMD_SET_MESSAGE_INTERVAL: -1 stops, 0 restores the default, else 1e6 / interval Hz."""
        entry = mavutil.mavlink.mavlink_map.get(msg_id)
        name = entry.msgname if entry is not None else None
        if name not in self.streams.streamable:
            if self.flavour == 'ardupilot':   # GCS_Common.cpp set_mavlink_message_id_interval
                self.ap.say(now, f'No ap_message for mavlink id ({msg_id})')
            return p.MAV_RESULT_FAILED
        if interval_us < 0:
            self.streams.set_rate(name, 0.0)
        elif interval_us == 0:
            self.streams.set_rate(name, self.streams.defaults_hz.get(name, 0.0))
        else:
            self.streams.set_rate(name, 1e6 / max(interval_us, 1000.0))
        return p.MAV_RESULT_ACCEPTED

    def on_request_data_stream(self, msg):
        """ArduPilot GCS_MAVLINK::handle_request_data_stream: sets the rate of every message of the group."""
        groups = p.COPTER_DATA_STREAMS if msg.req_stream_id == p.MAV_DATA_STREAM_ALL else {
            msg.req_stream_id: p.COPTER_DATA_STREAMS.get(msg.req_stream_id, ())}
        rate = float(msg.req_message_rate) if msg.start_stop else 0.0
        for names in groups.values():
            for name in names:
                self.streams.set_rate(name, rate)

    def send_param(self, name):
        value, mav_type = self.ap.params.encode(name)
        self.mav.param_value_send(name.encode(), value, mav_type, len(self.ap.params.order),
                                  self.ap.params.index(name))

    def on_param_set(self, msg, now):
        name = msg.param_id.rstrip('\x00') if isinstance(msg.param_id, str) else msg.param_id
        if name not in self.ap.params.specs:
            self.ap.say(now, f'PARAM_SET: {name} unknown')
            return
        try:
            self.ap.params.set(name, self.ap.params.decode(name, msg.param_value, msg.param_type))
        except ValueError as exc:
            self.ap.say(now, f'PARAM_SET refused: {exc}')
        self.send_param(name)   # the new value, or the unchanged one when refused (parameter protocol)

    # --- telemetry ----------------------------------------------------------------------------------------

    def send_telemetry(self, now):
        bucketed = self.flavour == 'ardupilot'
        for name in self.streams.due(now, bucketed):
            self.send_message(name, now)
        if bucketed and self.queue and now >= self.next_burst_s:
            for packed in self.queue:
                self.conn.write(packed)
            self.queue.clear()
            self.next_burst_s = now + self.rng.uniform(0.0, self.burst_s)

    def _emit(self, msg):
        if self.flavour == 'ardupilot' and self.burst_s > 0:
            self.queue.append(msg.pack(self.mav))
            self.mav.seq = (self.mav.seq + 1) % 256
        else:
            self.mav.send(msg)

    def _snapshot(self, t_sample, state, f_body):
        """Everything the messages say about one telemetry sample, in MAVLink frames (computed once a sample)."""
        if self._snap is not None and self._snap[0] == t_sample:
            return self._snap[1]
        pos, vel = ned.enu_to_ned(state.position), ned.enu_to_ned(state.velocity)
        q = ned.attitude_to_ned_wxyz(state.quaternion)
        w, x, y, z = q
        roll, pitch, yaw = (float(a) for a in rotations.to_euler(np.array([x, y, z, w])))
        snap = dict(pos=pos, vel=vel, q=q, rates=[float(v) for v in ned.flu_to_frd(state.body_rates)],
                    acc=[float(v) for v in ned.flu_to_frd(f_body)], roll=roll, pitch=pitch, yaw=yaw,
                    lat=HOME_LAT_DEG + math.degrees(pos[0] / EARTH_RADIUS_M),
                    lon=HOME_LON_DEG + math.degrees(pos[1] / (EARTH_RADIUS_M * math.cos(math.radians(HOME_LAT_DEG)))),
                    alt_m=HOME_ALT_M - pos[2])
        self._snap = (t_sample, snap)
        return snap

    def send_message(self, name, now):
        sample = self.telemetry.read(now)
        if sample is None:
            return
        t_sample, (state, f_body) = sample
        boot_ms = int(self.boot_s(t_sample) * 1000) & 0xFFFFFFFF
        boot_us = int(self.boot_s(t_sample) * 1e6)
        m = mavutil.mavlink
        snap = self._snapshot(t_sample, state, f_body)
        pos, vel, q, rates, acc = snap['pos'], snap['vel'], snap['q'], snap['rates'], snap['acc']
        roll, pitch, yaw = snap['roll'], snap['pitch'], snap['yaw']
        lat, lon, alt_m = snap['lat'], snap['lon'], snap['alt_m']
        voltage_v = 16.8 - 0.002 * now
        remaining = int(max(0.0, 100.0 - 0.02 * now))
        current_ca = 1500 if self.ap.armed else 50
        if name == 'HEARTBEAT':
            status = p.MAV_STATE_ACTIVE if self.ap.armed else p.MAV_STATE_STANDBY
            msg = m.MAVLink_heartbeat_message(p.MAV_TYPE_QUADROTOR, self.ap.autopilot_id, self.ap.base_mode,
                                              self.ap.custom_mode, status, 3)
        elif name == 'ATTITUDE':
            msg = m.MAVLink_attitude_message(boot_ms, roll, pitch, yaw, *rates)
        elif name == 'ATTITUDE_QUATERNION':
            msg = m.MAVLink_attitude_quaternion_message(boot_ms, *q, *rates, [0.0, 0.0, 0.0, 0.0])
        elif name == 'LOCAL_POSITION_NED':
            msg = m.MAVLink_local_position_ned_message(boot_ms, *map(float, pos), *map(float, vel))
        elif name == 'ODOMETRY':
            # PX4 v1.14+ mavlink/streams/ODOMETRY.hpp: frame_id LOCAL_NED, child_frame_id from the estimator's
            # velocity_frame, which EKF2 publishes as VELOCITY_FRAME_NED: velocity in local NED, not body
            nan21 = [float('nan')] * 21
            msg = m.MAVLink_odometry_message(boot_us, p.MAV_FRAME_LOCAL_NED, p.MAV_FRAME_LOCAL_NED,
                                             *map(float, pos), q, *map(float, vel), *rates, nan21, nan21,
                                             0, p.MAV_ESTIMATOR_TYPE_AUTOPILOT, 100)
        elif name == 'GLOBAL_POSITION_INT':
            msg = m.MAVLink_global_position_int_message(boot_ms, int(lat * 1e7), int(lon * 1e7), int(alt_m * 1000),
                                                        int(-pos[2] * 1000), *(int(v * 100) for v in vel),
                                                        int(math.degrees(yaw) % 360 * 100))
        elif name == 'HIGHRES_IMU':
            msg = m.MAVLink_highres_imu_message(boot_us, *acc, *rates, 0.2, 0.0, 0.4, 1013.0, 0.0,
                                                float(alt_m), 20.0, 0x1FFF, 0)
        elif name in ('RAW_IMU', 'SCALED_IMU', 'SCALED_IMU2'):   # milli-g, milli-rad/s, milli-gauss
            mg = [int(np.clip(a / GRAVITY_MPS2 * 1000.0, -32767, 32767)) for a in acc]
            mrad = [int(np.clip(r * 1000.0, -32767, 32767)) for r in rates]
            if name == 'RAW_IMU':
                msg = m.MAVLink_raw_imu_message(boot_us, *mg, *mrad, 200, 0, 400, 0, 2000)
            else:
                cls = m.MAVLink_scaled_imu_message if name == 'SCALED_IMU' else m.MAVLink_scaled_imu2_message
                msg = cls(boot_ms, *mg, *mrad, 200, 0, 400, 2000)
        elif name == 'SYS_STATUS':
            present, enabled, health = self.ap.sys_status_bits(now)
            msg = m.MAVLink_sys_status_message(present, enabled, health, 200, int(voltage_v * 1000), current_ca,
                                               remaining, 0, 0, 0, 0, 0, 0, 0, 0, 0)
        elif name == 'BATTERY_STATUS':
            cells = [int(voltage_v * 250)] * 4 + [0xFFFF] * 6
            msg = m.MAVLink_battery_status_message(0, 0, 3, 2500, cells, current_ca, -1, -1, remaining, 0, 0,
                                                   [0, 0, 0, 0], 0, 0)
        elif name == 'TIMESYNC':   # PX4 onboard mode asks for the companion's time (mavlink_timesync.cpp)
            msg = m.MAVLink_timesync_message(0, int(self.boot_s(now) * 1e9))
        elif name == 'VFR_HUD':
            msg = m.MAVLink_vfr_hud_message(0.0, float(np.linalg.norm(vel[:2])), int(math.degrees(yaw) % 360),
                                            int(100 * self.ap.armed), float(alt_m), float(-vel[2]))
        elif name == 'SYSTEM_TIME':
            msg = m.MAVLink_system_time_message(int(time.time() * 1e6), boot_ms)
        elif name == 'SCALED_PRESSURE':
            msg = m.MAVLink_scaled_pressure_message(boot_ms, 1013.25 - 0.12 * float(-pos[2]), 0.0, 2000)
        elif name == 'AHRS2':
            msg = m.MAVLink_ahrs2_message(roll, pitch, yaw, float(alt_m), int(lat * 1e7), int(lon * 1e7))
        elif name == 'POWER_STATUS':
            msg = m.MAVLink_power_status_message(5000, 5000, 0)
        elif name == 'MEMINFO':
            msg = m.MAVLink_meminfo_message(0, 65535)
        elif name == 'VIBRATION':
            msg = m.MAVLink_vibration_message(boot_us, 0.1, 0.1, 0.1, 0, 0, 0)
        else:
            return
        self._emit(msg)

    def send_statustext(self, text):
        """MAV_SEVERITY_INFO; a text over 50 bytes goes in 50-byte chunks sharing a non-zero id, chunk_seq
        counting up, the last one shorter (NUL-terminated) as both autopilots send it (PX4
        src/modules/mavlink/streams/STATUSTEXT.hpp, ArduPilot libraries/GCS_MAVLink/GCS_Common.cpp)."""
        data = text.encode()
        if len(data) <= 50:
            self.mav.statustext_send(6, data, 0, 0)
            return
        self.statustext_id = self.statustext_id % 0xFFFF + 1
        for seq, start in enumerate(range(0, len(data) + 1, 50)):
            self.mav.statustext_send(6, data[start:start + 50], self.statustext_id, seq)

    def send_log(self):
        for _, text in self.ap.log[self.log_index:]:
            self.send_statustext(text)
            print(f'mavlink_vehicle: {text}', flush=True)
        self.log_index = len(self.ap.log)


def _param(text):
    name, sep, value = text.partition('=')
    try:
        return name.strip().upper(), float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f'--param needs NAME=NUMBER, got {text!r}') from None


MOCAP_OPTIONS = ('frame', 'rate_hz', 'position_noise_m', 'attitude_noise_rad', 'latency_s')   # --mocap-<option>


def mocap_publisher(args, wall0_ns):
    """--mocap-topic: the motion-capture stand-in (quad_vehicle_emu.mocap, rclpy imported then), else None; a
    --mocap-* option without the topic is refused."""
    given = {k: getattr(args, f'mocap_{k}') for k in MOCAP_OPTIONS if getattr(args, f'mocap_{k}') is not None}
    if not args.mocap_topic:
        if given:
            name = next(iter(given))
            raise ValueError(f'--mocap-{name.replace("_", "-")} = {given[name]!r} refused: needs --mocap-topic')
        return None
    from quad_sim.mocap import MocapConfig
    from quad_vehicle_emu.mocap import DEFAULTS, MocapPublisher, MocapStandIn

    frame = given.pop('frame', 'enu')
    config = MocapConfig(**{**DEFAULTS, **given})
    return MocapPublisher(MocapStandIn(config, frame, wall0_ns, args.loop_rate_hz, args.seed), args.mocap_topic)


def build_parser():
    ap = argparse.ArgumentParser(prog='mavlink_vehicle', description=__doc__.split('\n\n')[0])
    ap.add_argument('--autopilot', choices=('px4', 'ardupilot'), default='px4')
    add_plant_arguments(ap)
    ap.add_argument('--url', default=None, help='pymavlink connection (default: px4 udpout:127.0.0.1:14540, '
                    'ardupilot tcpin:127.0.0.1:5760)')
    ap.add_argument('--system-id', type=int, default=None,
                    help='its MAVLink system id: = --param MAV_SYS_ID=N (px4) / SYSID_THISMAV=N (ardupilot); default 1')
    ap.add_argument('--hover-throttle', type=float, default=0.5,
                    help="the vehicle's true hover thrust (MPC_THR_HOVER / MOT_THST_HOVER start equal to it)")
    ap.add_argument('--param', type=_param, action='append', default=[], metavar='NAME=VALUE',
                    help='onboard parameter at boot, e.g. GUID_OPTIONS=8, COM_OF_LOSS_T=3 (repeatable)')
    ap.add_argument('--guid-options', type=int, default=None, help='ArduPilot: = --param GUID_OPTIONS=N')
    ap.add_argument('--offboard-loss-s', type=float, default=None, help='PX4: = --param COM_OF_LOSS_T=S')
    ap.add_argument('--guided-timeout-s', type=float, default=None, help='ArduPilot: = --param GUID_TIMEOUT=S')
    ap.add_argument('--telemetry-latency-s', type=float, default=None, help='px4 0.02, ardupilot 0.035 (+ its bursts)')
    ap.add_argument('--burst-s', type=float, default=None, help='ArduPilot: telemetry leaves in bursts up to '
                    'this far apart (0.04); 0 sends each message at once')
    ap.add_argument('--boot-offset-s', type=float, default=37.0, help='the vehicle booted this long before us')
    ap.add_argument('--clock-rate', type=float, default=1.0,
                    help="the vehicle's clock rate against ours (PX4 SIH ran 0.984-0.993 of wall time), 0.5..2")
    ap.add_argument('--loop-rate-hz', type=float, default=100.0)
    ap.add_argument('--signing-key-file', default='', help='MAVLink 2 signing key; empty: unsigned')
    ap.add_argument('--realtime-priority', type=int, default=0,
                    help='SCHED_FIFO priority 1..99 for the emulator (a flight controller has a processor of its '
                         "own: under load the stand-in must not stall where the real one would not); 0: off")
    ap.add_argument('--duration-s', type=float, default=0.0, help='stop after this long (0: run until killed)')
    ap.add_argument('--mocap-topic', default='',
                    help='publish the truth as a motion-capture system does (geometry_msgs/PoseStamped stamped at '
                         'the capture instant; rclpy, ROS_DOMAIN_ID) on this topic, e.g. external/pose; empty: off')
    ap.add_argument('--mocap-frame', default=None, help='enu (default) | y_up (Motive\'s default world)')
    ap.add_argument('--mocap-rate-hz', type=float, default=None, help='frames per second, <= --loop-rate-hz (100)')
    ap.add_argument('--mocap-position-noise-m', type=float, default=None, help='RMS per axis (0.001)')
    ap.add_argument('--mocap-attitude-noise-rad', type=float, default=None, help='RMS per body axis (0.002)')
    ap.add_argument('--mocap-latency-s', type=float, default=None, help='capture to publication (0.01)')
    return ap


def main(args=None):
    args = build_parser().parse_args(args)
    if args.url is None:
        args.url = 'udpout:127.0.0.1:14540' if args.autopilot == 'px4' else 'tcpin:127.0.0.1:5760'
    legacy = ({'COM_OF_LOSS_T': args.offboard_loss_s} if args.autopilot == 'px4' else
              {'GUID_OPTIONS': args.guid_options, 'GUID_TIMEOUT': args.guided_timeout_s})
    legacy[SYSTEM_ID_PARAMS[args.autopilot]] = args.system_id
    for name, value in legacy.items():
        given = [v for k, v in args.param if k == name]
        if value is not None and given and float(given[-1]) != float(value):
            print(f'mavlink_vehicle: --param {name}={given[-1]} and its option ({value}) disagree: give one',
                  file=sys.stderr)
            return 2
    args.param += [(k, v) for k, v in legacy.items() if v is not None]
    if args.realtime_priority != 0 and not 1 <= args.realtime_priority <= 99:
        print(f'mavlink_vehicle: --realtime-priority = {args.realtime_priority} refused: must be 0 (off) or 1..99',
              file=sys.stderr)
        return 2
    try:
        vehicle = MavlinkVehicle(args)
    except (ValueError, OSError) as exc:
        print(f'mavlink_vehicle: {exc}', file=sys.stderr)
        return 2
    print(f'mavlink_vehicle: {args.autopilot} system {vehicle.system_id} on {args.url}', flush=True)
    scheduling, _ = apply_or_report(args.realtime_priority,
                                    lambda error: print(f'mavlink_vehicle: {error}', file=sys.stderr, flush=True))
    print(f'mavlink_vehicle: scheduling {scheduling}', flush=True)
    print(f'mavlink_vehicle: boot clock = {args.boot_offset_s} s + {args.clock_rate} x (wall clock - '
          f'{vehicle.wall0_ns} ns)', flush=True)
    freeze_startup_heap()   # no full collection of the start-up heap while it flies (an autopilot does not pause)
    try:
        vehicle.run()
    except KeyboardInterrupt:
        pass
    finally:
        if vehicle.mocap is not None:
            vehicle.mocap.close()
    return 0


if __name__ == '__main__':
    sys.exit(main())
