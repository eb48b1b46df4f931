"""mavlink_vehicle: the quad_sim plant and onboard autopilot behind a real MAVLink endpoint, in real time.

It behaves like PX4 (HEARTBEAT autopilot 12, custom_mode main/sub encoding, OFFBOARD entered only
while a >= 2 Hz SET_ATTITUDE_TARGET stream is live and left for AUTO.LAND after COM_OF_LOSS_T without
one, collective thrust T = thr_hover f / g) or like ArduPilot Copter (autopilot 3, mode numbers,
GUIDED_NOGPS with climb-rate or, with GUID_OPTIONS bit 3, thrust semantics boosted by 1/cos(tilt);
after GUID_TIMEOUT without a setpoint it levels and holds altitude and stays in GUIDED_NOGPS).
LAND descends over the point where it began and disarms on the ground. The frame and mode
conventions are quad_bridge's (one place for both ends of the link).

    python -m quad_sim.mavlink_vehicle --autopilot px4 --url udpout:127.0.0.1:14540
"""

import argparse
import math
import sys
import time

import numpy as np

from quad_bridge import autopilot as ap
from quad_bridge import frames
from quad_bridge.link import RateMeter, load_signing_key
from quad_bridge.mavlink_client import mavlink, mavutil
from quad_common import rotations
from quad_common.types import GRAVITY_MPS2, AttitudeSetpoint, State
from quad_common.vehicle import load_vehicle
from quad_sim.simulator import Simulator

DEFAULT_VEHICLE = 'config/vehicles/px4_quad.yaml'
OFFBOARD_MIN_RATE_HZ = 2.0
HOLD_TILT_MAX_RAD = math.radians(20.0)
CLIMB_RATE_GAIN = 3.0          # 1/s, ArduPilot's vertical speed loop in climb-rate mode / level hold
DEFAULT_INTERVALS_S = {'ATTITUDE_QUATERNION': 0.02, 'LOCAL_POSITION_NED': 0.02, 'HIGHRES_IMU': 0.02,
                       'SYS_STATUS': 0.5, 'BATTERY_STATUS': 1.0, 'HEARTBEAT': 1.0}


class OnboardAutopilot:
    """Modes, arming and setpoint semantics of the emulated autopilot; no sockets, times in seconds."""

    def __init__(self, flavour: str, hover_throttle: float, guid_options: int = 0, offboard_loss_s: float = 1.0,
                 guided_timeout_s: float = 3.0, land_speed_mps: float = 0.7, speed_up_mps: float = 2.5,
                 speed_down_mps: float = 1.5):
        self.autopilot = ap.MAV_AUTOPILOT_PX4 if flavour == 'px4' else ap.MAV_AUTOPILOT_ARDUPILOTMEGA
        self.hover_throttle = hover_throttle
        self.thrust_is_thrust = (self.autopilot == ap.MAV_AUTOPILOT_PX4
                                 or bool(guid_options & ap.GUID_OPTIONS_THRUST_BIT))
        self.offboard_loss_s = offboard_loss_s
        self.guided_timeout_s = guided_timeout_s
        self.land_speed_mps = land_speed_mps
        self.speed_up_mps, self.speed_down_mps = speed_up_mps, speed_down_mps
        self.mode = 'POSCTL' if self.autopilot == ap.MAV_AUTOPILOT_PX4 else 'STABILIZE'
        self.armed = False
        self.setpoint = None          # (q_enu, thrust, body rates FLU or None)
        self.setpoint_time_s = -math.inf
        self.setpoints = RateMeter()
        self.hold_position = None
        self.log = []                 # (time_s, text) of mode changes, for STATUSTEXT

    @property
    def custom_mode(self) -> int:
        return ap.custom_mode_of(self.autopilot, *ap.mode_from_name(self.autopilot, self.mode))

    def _set_mode(self, mode, now_s, why):
        if mode != self.mode:
            self.mode = mode
            self.hold_position = None
            self.log.append((now_s, f'mode {mode}: {why}'))

    def on_attitude_target(self, q_ned, rates_frd, thrust, rates_ignored, now_s):
        """Raises ValueError (setpoint ignored) on a zero or non-finite quaternion, thrust or rates."""
        q_ned = rotations.normalize(q_ned)
        if not math.isfinite(thrust) or not (rates_ignored or np.all(np.isfinite(rates_frd))):
            raise ValueError(f'non-finite SET_ATTITUDE_TARGET: thrust {thrust}, rates {list(rates_frd)}')
        self.setpoint = (frames.quaternion_ned_to_enu(q_ned), float(thrust),
                         None if rates_ignored else frames.body_flu_frd(rates_frd))
        self.setpoint_time_s = now_s
        self.setpoints.tick(now_s)

    def command(self, command: int, params, landed: bool, now_s: float) -> int:
        """MAV_RESULT of a COMMAND_LONG."""
        if command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            arm = params[0] > 0.5
            if not arm and not landed and int(params[1]) != 21196:
                return mavlink.MAV_RESULT_DENIED
            self.armed = arm
            self.log.append((now_s, 'armed' if arm else 'disarmed'))
            return mavlink.MAV_RESULT_ACCEPTED
        if command == mavlink.MAV_CMD_DO_SET_MODE:
            if int(params[0]) & ap.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED == 0:
                return mavlink.MAV_RESULT_DENIED
            name = ap.mode_name(self.autopilot, ap.custom_mode_of(self.autopilot, params[1], params[2]))
            try:
                ap.mode_from_name(self.autopilot, name)
            except ValueError:
                return mavlink.MAV_RESULT_DENIED
            if name == 'OFFBOARD' and not self.stream_live(now_s):  # PX4: offboard needs the setpoint stream first
                self.log.append((now_s, f'OFFBOARD refused: setpoints at {self.setpoints.rate_hz(now_s):.1f} Hz'))
                return mavlink.MAV_RESULT_DENIED
            self._set_mode(name, now_s, 'commanded')
            return mavlink.MAV_RESULT_ACCEPTED
        if command == mavlink.MAV_CMD_NAV_LAND:
            self._set_mode(ap.land_mode(self.autopilot), now_s, 'commanded')
            return mavlink.MAV_RESULT_ACCEPTED
        if command in (mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAV_CMD_REQUEST_MESSAGE):
            return mavlink.MAV_RESULT_ACCEPTED
        return mavlink.MAV_RESULT_UNSUPPORTED

    def stream_live(self, now_s) -> bool:
        return (self.setpoints.rate_hz(now_s) >= OFFBOARD_MIN_RATE_HZ
                and now_s - self.setpoint_time_s < self.offboard_loss_s)

    def update(self, state: State, landed: bool, now_s: float) -> AttitudeSetpoint | None:
        """The attitude/thrust the attitude loop flies now (None: disarmed, motors idle)."""
        if self.armed and landed and self.mode == ap.land_mode(self.autopilot) and self.hold_position is not None:
            self.armed = False
            self.log.append((now_s, 'landed: disarmed'))
        if not self.armed:
            return None
        age_s = now_s - self.setpoint_time_s
        if self.mode == 'OFFBOARD' and age_s > self.offboard_loss_s:
            self._set_mode('AUTO.LAND', now_s, f'offboard setpoints lost for {self.offboard_loss_s} s')
        if self.mode == ap.offboard_mode(self.autopilot):
            if self.autopilot == ap.MAV_AUTOPILOT_ARDUPILOTMEGA and age_s > self.guided_timeout_s:
                return self._level_hold(state)  # GUID_TIMEOUT: level, hold altitude, stay in GUIDED_NOGPS
            return self._fly_setpoint(state)
        if self.hold_position is None:
            self.hold_position = state.position.copy()
        if self.mode == ap.land_mode(self.autopilot):
            return self._position_hold(state, self.hold_position, -self.land_speed_mps)
        if landed:
            return AttitudeSetpoint(quaternion=rotations.from_yaw(_yaw(state)), specific_force_mps2=0.0)
        return self._position_hold(state, self.hold_position, None)

    def _fly_setpoint(self, state):
        q, thrust, rates = self.setpoint
        if self.thrust_is_thrust:
            f = ap.specific_force_from_thrust(self.autopilot, thrust, self.hover_throttle, q)
        else:
            climb = ap.thrust_to_climb_rate(thrust, self.speed_up_mps, self.speed_down_mps)
            f = self._climb_force(state, climb, q)
        return AttitudeSetpoint(quaternion=q, specific_force_mps2=f, body_rates=rates)

    def _climb_force(self, state, climb_rate_mps, q):
        a_z = CLIMB_RATE_GAIN * (climb_rate_mps - state.velocity[2])
        return (GRAVITY_MPS2 + a_z) / max(ap.tilt_cos(q), ap.ANGLE_BOOST_COS_MIN)

    def _level_hold(self, state):
        q = rotations.from_yaw(_yaw(state))
        return AttitudeSetpoint(quaternion=q, specific_force_mps2=self._climb_force(state, 0.0, q))

    def _position_hold(self, state, target, descent_rate_mps):
        """Onboard position hold (descent_rate None) or landing over target at a fixed descent rate."""
        a = 1.0 * (target - state.position) - 1.5 * state.velocity
        if descent_rate_mps is None:
            a[2] = 2.0 * (target[2] - state.position[2]) - 2.5 * state.velocity[2]
        else:
            a[2] = CLIMB_RATE_GAIN * (descent_rate_mps - state.velocity[2])
        thrust = a + np.array([0.0, 0.0, GRAVITY_MPS2])
        horizontal = np.linalg.norm(thrust[:2])
        limit = thrust[2] * math.tan(HOLD_TILT_MAX_RAD)
        if horizontal > limit:
            thrust[:2] *= limit / horizontal
        z_b = thrust / np.linalg.norm(thrust)
        yaw = _yaw(state)
        x_c = np.array([math.cos(yaw), math.sin(yaw), 0.0])
        y_b = np.cross(z_b, x_c)
        y_b /= np.linalg.norm(y_b)
        R = np.column_stack([np.cross(y_b, z_b), y_b, z_b])
        return AttitudeSetpoint(quaternion=rotations.from_matrix(R), specific_force_mps2=float(np.linalg.norm(thrust)))


def _yaw(state):
    return float(rotations.to_euler(state.quaternion)[2])


class MavlinkVehicle:
    """Socket, clocks and telemetry around a Simulator and an OnboardAutopilot."""

    def __init__(self, args):
        self.args = args
        self.sim = Simulator(load_vehicle(args.vehicle), physics_rate_hz=args.physics_rate_hz,
                             initial_position=args.initial_position, initial_yaw=args.initial_yaw,
                             setpoint_timeout_s=1e6)
        self.sim.warm_up()  # before the first heartbeat: compiling mid-flight would stall the link for seconds
        self.autopilot = OnboardAutopilot(args.autopilot, args.hover_throttle, guid_options=args.guid_options,
                                          offboard_loss_s=args.offboard_loss_s, guided_timeout_s=args.guided_timeout_s)
        if not self.sim.landed:  # starts in the air: armed, holding position (like sim_node starts hovering)
            self.autopilot.armed = True
            self.autopilot.mode = ap.hold_mode(self.autopilot.autopilot) if args.autopilot == 'px4' else 'LOITER'
        self.sim.armed = self.autopilot.armed
        self.conn = mavutil.mavlink_connection(args.url, source_system=args.system_id, source_component=1,
                                               autoreconnect=True, robust_parsing=True)
        if args.signing_key_file:  # signs what it sends and accepts only messages signed with the same key
            self.conn.setup_signing(load_signing_key(args.signing_key_file), sign_outgoing=True)
        self.intervals_s = dict(DEFAULT_INTERVALS_S)
        self.next_due_s = {}
        self.t0 = time.monotonic()
        self.log_index = 0

    def now_s(self):
        return time.monotonic() - self.t0

    def run(self):
        tick_s = 1.0 / self.args.loop_rate_hz
        steps_per_tick = self.sim.steps_in(round(tick_s * self.args.physics_rate_hz) / self.args.physics_rate_hz)
        while self.args.duration_s <= 0 or self.now_s() < self.args.duration_s:
            self.receive()
            now = self.now_s()
            sp = self.autopilot.update(self.sim.state, self.sim.landed, now)
            self.sim.armed = sp is not None
            if sp is not None:
                self.sim.set_setpoint(sp)
            lag_steps = int((now - self.sim.time_s) * self.args.physics_rate_hz)
            self.sim.advance_steps(min(max(lag_steps, 0), 5 * steps_per_tick))
            self.send_telemetry(now)
            self.send_log()
            sleep_s = self.sim.time_s + tick_s - self.now_s()
            if sleep_s > 0:
                time.sleep(sleep_s)

    def receive(self):
        for _ in range(200):
            try:
                msg = self.conn.recv_match(blocking=False)
            except Exception:
                continue
            if msg is None:
                return
            kind = msg.get_type()
            if kind == 'BAD_DATA' or getattr(msg, 'target_system', self.args.system_id) not in (0, self.args.system_id):
                continue
            try:
                self.handle(msg, kind)
            except (ValueError, TypeError, OverflowError) as exc:  # malformed fields (NaN mode numbers, ...)
                print(f'mavlink_vehicle: {kind} ignored: {exc}', flush=True)

    def handle(self, msg, kind):
        now = self.now_s()
        if kind == 'SET_ATTITUDE_TARGET':
            rates_ignored = msg.type_mask & 7 == 7
            self.autopilot.on_attitude_target(frames.from_mavlink_quaternion(msg.q),
                                              [msg.body_roll_rate, msg.body_pitch_rate, msg.body_yaw_rate],
                                              msg.thrust, rates_ignored, now)
        elif kind == 'COMMAND_LONG':
            params = [msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7]
            result = self.autopilot.command(msg.command, params, self.sim.landed, now)
            if msg.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
                self.set_interval(int(msg.param1), msg.param2)
            self.conn.mav.command_ack_send(msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())
        elif kind == 'TIMESYNC' and msg.tc1 == 0:
            self.conn.mav.timesync_send(time.monotonic_ns(), msg.ts1)

    def set_interval(self, msg_id, interval_us):
        entry = mavlink.mavlink_map.get(msg_id)
        if entry is None:
            return
        name = entry.msgname
        if interval_us < 0:
            self.intervals_s.pop(name, None)
        elif interval_us > 0:
            self.intervals_s[name] = interval_us * 1e-6

    def due(self, name, now):
        interval = self.intervals_s.get(name)
        due_s = self.next_due_s.get(name, 0.0)
        if interval is None or now < due_s:
            return False
        self.next_due_s[name] = max(due_s + interval, now - interval)
        return True

    def send_telemetry(self, now):
        mav, ap_ = self.conn.mav, self.autopilot
        boot_ms = int(now * 1000)
        truth = self.sim.state
        ned = frames.state_to_ned(truth)
        if self.due('HEARTBEAT', now):
            base = ap.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (ap.MAV_MODE_FLAG_SAFETY_ARMED if ap_.armed else 0)
            status = mavlink.MAV_STATE_ACTIVE if ap_.armed else mavlink.MAV_STATE_STANDBY
            mav.heartbeat_send(mavlink.MAV_TYPE_QUADROTOR, ap_.autopilot, base, ap_.custom_mode, status)
        if self.due('ATTITUDE_QUATERNION', now):
            mav.attitude_quaternion_send(boot_ms, *frames.to_mavlink_quaternion(ned.quaternion),
                                         *map(float, ned.body_rates))
        if self.due('LOCAL_POSITION_NED', now):
            mav.local_position_ned_send(boot_ms, *map(float, ned.position), *map(float, ned.velocity))
        if self.due('HIGHRES_IMU', now):
            acc = frames.body_flu_frd(self.sim.specific_force_body_mps2)
            mav.highres_imu_send(int(now * 1e6), *map(float, acc), *map(float, ned.body_rates), 0.0, 0.0, 0.0,
                                 1013.0, 0.0, float(-ned.position[2]), 20.0, 0x3F)
        voltage_v = 16.8 - 0.002 * now
        remaining = int(max(0.0, 100.0 - 0.02 * now))
        if self.due('SYS_STATUS', now):
            sensors = mavlink.MAV_SYS_STATUS_PREARM_CHECK
            mav.sys_status_send(sensors, sensors, sensors, 200, int(voltage_v * 1000), 1500 if ap_.armed else 50,
                                remaining, 0, 0, 0, 0, 0, 0)
        if self.due('BATTERY_STATUS', now):
            cells = [int(voltage_v * 250)] * 4 + [0xFFFF] * 6
            mav.battery_status_send(0, mavlink.MAV_BATTERY_FUNCTION_ALL, mavlink.MAV_BATTERY_TYPE_LIPO, 2500,
                                    cells, 1500 if ap_.armed else 50, -1, -1, remaining)

    def send_log(self):
        for _, text in self.autopilot.log[self.log_index:]:
            self.conn.mav.statustext_send(mavlink.MAV_SEVERITY_INFO, text.encode()[:50])
            print(f'mavlink_vehicle: {text}', flush=True)
        self.log_index = len(self.autopilot.log)


def _triple(text):
    values = [float(v) for v in text.split(',')]
    if len(values) != 3 or not all(map(math.isfinite, values)):
        raise argparse.ArgumentTypeError(f'needs 3 finite numbers x,y,z, got {text!r}')
    return values


def build_parser():
    p = argparse.ArgumentParser(prog='mavlink_vehicle', description=__doc__.split('\n\n')[0])
    p.add_argument('--autopilot', choices=('px4', 'ardupilot'), default='px4')
    p.add_argument('--url', default=None, help='pymavlink connection (default: px4 udpout:127.0.0.1:14540, '
                   'ardupilot tcpin:127.0.0.1:5760)')
    p.add_argument('--system-id', type=int, default=1)
    p.add_argument('--vehicle', default=DEFAULT_VEHICLE, help='vehicle YAML (quad_common.vehicle)')
    p.add_argument('--initial-position', type=_triple, default=[0.0, 0.0, 0.0],
                   help='x,y,z in map (ENU), m; above the floor: starts armed, holding (AUTO.LOITER / LOITER)')
    p.add_argument('--initial-yaw', type=float, default=0.0, help='rad, ENU')
    p.add_argument('--hover-throttle', type=float, default=0.5, help='thrust that hovers (MPC_THR_HOVER)')
    p.add_argument('--guid-options', type=int, default=8, help='ArduPilot GUID_OPTIONS (bit 3: thrust, not climb)')
    p.add_argument('--offboard-loss-s', type=float, default=1.0, help='PX4 COM_OF_LOSS_T')
    p.add_argument('--guided-timeout-s', type=float, default=3.0, help='ArduPilot GUID_TIMEOUT')
    p.add_argument('--physics-rate-hz', type=float, default=500.0)
    p.add_argument('--loop-rate-hz', type=float, default=100.0)
    p.add_argument('--signing-key-file', default='', help='MAVLink 2 signing key (as the bridge\'s); empty: unsigned')
    p.add_argument('--duration-s', type=float, default=0.0, help='stop after this long (0: run until killed)')
    return p


def main(args=None):
    args = build_parser().parse_args(args)
    if args.url is None:
        args.url = 'udpout:127.0.0.1:14540' if args.autopilot == 'px4' else 'tcpin:127.0.0.1:5760'
    for name in ('hover_throttle',):
        if not 0.05 <= getattr(args, name) <= 0.95:
            print(f'mavlink_vehicle: --hover-throttle = {args.hover_throttle} must be in [0.05, 0.95]', file=sys.stderr)
            return 2
    try:
        vehicle = MavlinkVehicle(args)
    except (ValueError, OSError) as exc:
        print(f'mavlink_vehicle: {exc}', file=sys.stderr)
        return 2
    print(f'mavlink_vehicle: {args.autopilot} on {args.url}', flush=True)
    try:
        vehicle.run()
    except KeyboardInterrupt:
        pass
    return 0


if __name__ == '__main__':
    sys.exit(main())
