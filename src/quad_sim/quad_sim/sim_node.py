"""sim_node: the simulated vehicle on the ROS graph (docs/quad_sim.md).

lockstep: at sim time t_k publish odom (stamp t_k), then /clock (t_k); wait for a cmd/attitude_thrust stamped
>= t_k or lockstep_timeout_s of wall time; advance lockstep_period_s holding that setpoint. After such a timeout
each step waits LOST_STEP_TIMEOUT_S at most until a setpoint arrives again (a dead controller: the failsafe lands
the vehicle in seconds, not one step per timeout; a controller that was only slow catches up). Until the first
setpoint arrives, step k is re-published every 0.1 s (for nodes that join late), and the timeout advances
only when a controller (a cmd/attitude_thrust publisher with odom and /clock subscribers) is on the graph:
start-up order does not matter, and a controller whose first tick is after t = 0 still starts the run.
Followers (lockstep_followers, quad_common.lockstep): each step also waits, without a timeout, until every
follower has acknowledged odometry within FOLLOWER_LAG_STEPS of it, so a recorder that falls behind slows the run
instead of losing samples; on SIGINT/SIGTERM the loop stops advancing, publishes its final counts on diagnostics
and waits for the followers to acknowledge its last step (as long as they make progress: DRAIN_STALL_S).
A setpoint stamped more than one period ahead of sim time is refused (counted, warned): taken as "the newest",
it would make every later, correctly stamped one look old.
realtime: a wall-clock timer at odom_rate_hz advances the simulation to rtf * elapsed wall time.
"""

import math
import time

import rclpy
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Bool
from std_srvs.srv import Trigger
from trajectory_msgs.msg import MultiDOFJointTrajectory

try:  # not among the PyPI ROS wheels; present on every machine with ROS 2 installed
    from tf2_msgs.msg import TFMessage
except ImportError:
    TFMessage = None

from quad_common import cdr, contract, conversions, diagnostics, lockstep
from quad_common.hot_path import HotPathExecutor
from quad_common.node_main import run_node
from quad_common.params import Param
from quad_common.paths import resolve_config
from quad_common.ros_params import ParameterSet
from quad_common.vehicle import load_vehicle
from quad_common.world import load_world
from quad_sim.disturbances import load_profile
from quad_sim.simulator import PHYSICS_RATE_HZ, SimulationStopped, Simulator

NAME = 'sim_node'
DIAGNOSTICS_PERIOD_S = 1.0  # sim time
STARTUP_REPUBLISH_S = 0.1   # wall time between re-publications of the first step until a setpoint arrives
DRAIN_STALL_S = 30.0        # wall time, at shutdown, a follower may go without acknowledging anything new
FOLLOWER_WARN_S = 5.0       # wall time waiting for a follower before each warning naming it
LOST_STEP_TIMEOUT_S = 0.02  # wall time per step for a setpoint once one missed lockstep_timeout_s

SPECS = [
    Param('vehicle', 'config/vehicles/crazyflie.yaml', 'vehicle file (config/vehicles/*.yaml)', read_only=True),
    Param('plant', '', 'plant family member (config/plant_family.yaml) applied to the vehicle; empty: none',
          read_only=True),
    Param('initial_position', [0.0, 0.0, 1.0], 'start position, map frame (m); hovering unless on the floor',
          length=3, read_only=True),
    Param('initial_yaw', 0.0, 'start yaw (rad)', min=-math.pi, max=math.pi, read_only=True),
    Param('physics_rate_hz', PHYSICS_RATE_HZ, 'RK4 and onboard autopilot rate (Hz)', min=100.0, max=100000.0,
          read_only=True),
    Param('mode', 'lockstep', 'lockstep (deterministic, as fast as the graph) or realtime (paced by rtf)',
          choices=('lockstep', 'realtime'), read_only=True),
    Param('rtf', 1.0, 'realtime mode: simulated seconds per wall second', min=0.01, max=1000.0),
    Param('lockstep_period_s', 0.01, 'lockstep: sim time per setpoint (= 1 / controller rate_hz)',
          min=1e-4, max=1.0, read_only=True),
    Param('lockstep_timeout_s', 0.5, 'lockstep: wall time to wait for a setpoint before advancing anyway',
          min=0.001, max=60.0),
    Param('odom_rate_hz', 100.0, 'realtime mode: odom and /clock rate (Hz)', min=1.0, max=1000.0,
          read_only=True),
    Param('sensor_rate_hz', 20.0, 'imu, rotor_speeds and /tf rate in sim time (Hz), at most the odom rate; '
          '0: with every odom', min=0.0, max=1000.0, read_only=True),
    Param('disturbances', 'none', 'disturbance profile name in disturbances_file', read_only=True),
    Param('disturbances_file', 'config/disturbances.yaml', 'disturbance profiles file', read_only=True),
    Param('world', '', 'world file (boxes, JSON or YAML) for collisions; empty: none', read_only=True),
    Param('robot_radius_m', 0.1, 'collision radius around the vehicle centre (m)', min=0.0, max=5.0,
          read_only=True),
    Param('setpoint_timeout_s', 0.5, 'sim time without a setpoint before the landing failsafe',
          min=0.01, max=60.0, read_only=True),
    Param('max_tracking_error_m', 0.0, 'stop the run when farther than this from control/reference; 0: off',
          min=0.0, max=1000.0, read_only=True),
    Param('seed', 0, 'random seed of gusts and odometry noise', min=0, max=2**31 - 1, read_only=True),
    Param('lockstep_followers', '', 'lockstep: comma-separated node names whose acknowledgements each step waits for '
          '(quad_common.lockstep; e.g. recorder): nothing they record is lost', read_only=True),
]



def stamp_of(time_ns: int) -> Time:
    return Time(sec=time_ns // 1_000_000_000, nanosec=time_ns % 1_000_000_000)


class SimNode(Node):
    def __init__(self, **kwargs):
        super().__init__(NAME, **kwargs)
        self.params = ParameterSet(self, SPECS)
        p = self.params
        vehicle = load_vehicle(self._config(p['vehicle'], 'vehicle'), plant=p['plant'] or None)
        world = load_world(self._config(p['world'], 'world')) if p['world'] else None
        profile = load_profile(self._config(p['disturbances_file'], 'disturbances_file'), p['disturbances'])
        self.sim = Simulator(vehicle, physics_rate_hz=p['physics_rate_hz'], initial_position=p['initial_position'],
                             initial_yaw=p['initial_yaw'], disturbances=profile, world=world,
                             robot_radius_m=p['robot_radius_m'], seed=p['seed'],
                             setpoint_timeout_s=p['setpoint_timeout_s'])
        self.sim.warm_up()
        try:
            self.steps_per_period = self.sim.steps_in(p['lockstep_period_s'])
        except ValueError as exc:
            raise ValueError(f'lockstep_period_s: {exc}') from None
        self.followers = [f.strip() for f in p['lockstep_followers'].split(',') if f.strip()]
        c = contract
        pace = (lambda topic: lockstep.PACED) if self.followers else c.qos  # followers: paced, deep history
        self.odom_pub = self.create_publisher(Odometry, c.ODOM, pace(c.ODOM))
        self.clock_pub = self.create_publisher(ClockMsg, c.CLOCK, pace(c.CLOCK))
        self.tf_pub = self.create_publisher(TFMessage, c.TF, c.qos(c.TF)) if TFMessage else None
        if TFMessage is None:
            self.get_logger().warn('tf2_msgs is not installed here: /tf is not published (odom carries the pose)')
        self.imu_pub = self.create_publisher(Imu, c.IMU, pace(c.IMU))
        self.rotor_pub = self.create_publisher(JointState, c.ROTOR_SPEEDS, pace(c.ROTOR_SPEEDS))
        self.diag_pub = self.create_publisher(DiagnosticArray, c.DIAGNOSTICS, pace(c.DIAGNOSTICS))
        # the simulated vehicle flies our setpoints from the start (a bridge says so only during a hand-over)
        self.engaged_pub = self.create_publisher(Bool, c.ENGAGED, c.qos(c.ENGAGED))
        self.engaged_pub.publish(Bool(data=True))
        self.hot_subscriptions = [self.create_subscription(Imu, c.SETPOINT, self._on_setpoint, c.qos(c.SETPOINT),
                                                           raw=True)]
        self.acked_ns = dict.fromkeys(self.followers, -1)
        for follower in self.followers:
            self.hot_subscriptions.append(self.create_subscription(
                ClockMsg, lockstep.ack_topic(follower),
                lambda msg, f=follower: self._on_ack(f, msg), lockstep.ACK))
        self.stop_requested = lambda: False  # main() replaces it with its signal flag
        if p['max_tracking_error_m'] > 0:
            self.hot_subscriptions.append(self.create_subscription(
                MultiDOFJointTrajectory, c.REFERENCE, self._on_reference, c.qos(c.REFERENCE)))
        self.hot_timers = []
        self.create_service(Trigger, 'reset', self._on_reset)
        self._rotor_names = [f'rotor_{i}' for i in range(4)]
        self._odom_packer = cdr.OdometryPacker()
        self._wall = Clock(clock_type=ClockType.STEADY_TIME)
        self._sensor_period_ns = int(round(1e9 / p['sensor_rate_hz'])) if p['sensor_rate_hz'] > 0 else 0
        self._reset_bookkeeping()
        self.get_logger().info(
            f'{p["mode"]}: {vehicle.name} at {list(p["initial_position"])}, {p["physics_rate_hz"]:g} Hz physics, '
            f'disturbances {profile.name}, world {p["world"] or "none"}')

    def _config(self, path, name):
        try:
            return resolve_config(path)
        except FileNotFoundError as exc:
            raise ValueError(f'{name} = {path!r}: {exc}') from None

    def _reset_bookkeeping(self):
        self.setpoint_stamp_ns = -1
        self.setpoints_received = 0
        self.future_setpoints = 0
        self.controller_lost = False  # a setpoint missed lockstep_timeout_s: steps wait LOST_STEP_TIMEOUT_S at most
        self.steps_published = 0  # distinct odom (and /clock) stamps published
        self.last_odom_ns = -1
        self._events_reported = 0
        self._next_diagnostics_ns = 0
        self._next_sensors_ns = 0
        self._wall_start_s = time.monotonic()
        self._sim_start_ns = self.sim.time_ns

    # --- inputs ------------------------------------------------------------------------------------------

    def _on_setpoint(self, raw: bytes):
        """cmd/attitude_thrust, serialized (quad_common.cdr: the tick's critical path)."""
        stamp_ns = cdr.header_stamp_ns(raw, Imu)
        if stamp_ns < self.setpoint_stamp_ns:
            return  # older than the one applied
        period_ns = self.steps_per_period * self.sim.step_ns
        if stamp_ns > self.sim.time_ns + period_ns:
            self.future_setpoints += 1
            self.get_logger().warn(
                f'setpoint refused: stamped {stamp_ns * 1e-9:.3f} s, ahead of sim time {self.sim.time_s:.3f} s by '
                f'more than one period ({self.future_setpoints} so far; a clock other than /clock?)',
                throttle_duration_sec=1.0)
            return
        try:
            setpoint = cdr.imu_to_setpoint(raw)
            self.sim.set_setpoint(setpoint)
        except ValueError as exc:
            self.get_logger().warn(f'setpoint refused: {exc}', throttle_duration_sec=1.0)
            return
        self.setpoint_stamp_ns = stamp_ns
        self.setpoints_received += 1
        self.controller_lost = False

    def _on_ack(self, follower: str, msg: ClockMsg):
        self.acked_ns[follower] = max(self.acked_ns[follower], msg.clock.sec * 1_000_000_000 + msg.clock.nanosec)

    def followers_behind(self, stamp_ns: int) -> list[str]:
        """Followers whose newest acknowledged odometry is older than `stamp_ns`."""
        return [f for f, acked in self.acked_ns.items() if acked < stamp_ns]

    def _on_reference(self, msg: MultiDOFJointTrajectory):
        if msg.points and msg.points[0].transforms and self.sim.stopped is None:
            try:
                self.sim.check_tracking(conversions.vec3(msg.points[0].transforms[0].translation),
                                        self.params['max_tracking_error_m'])
            except SimulationStopped as exc:
                self._report_stop(exc)

    def _on_reset(self, request, response):
        self.sim.reset()
        self._reset_bookkeeping()
        response.success, response.message = True, 'simulation reset to its initial state; time restarts at 0'
        self.get_logger().info(response.message)
        return response

    # --- outputs -----------------------------------------------------------------------------------------

    def publish_step(self):
        """odom and then /clock at the current sim time (contract order); then, every 1 / sensor_rate_hz of sim
        time, /tf, imu and rotor_speeds (after /clock: the controller's tick does not wait for them)."""
        time_ns = self.sim.time_ns
        stamp = stamp_of(time_ns)
        self.odom_pub.publish(self._odom_packer.pack(self.sim.odometry_state(), time_ns))
        self.clock_pub.publish(ClockMsg(clock=stamp))
        if time_ns != self.last_odom_ns:  # the first step is re-published until a setpoint comes: one step
            self.steps_published += 1
        self.last_odom_ns = time_ns
        if time_ns >= self._next_sensors_ns:
            self._next_sensors_ns = time_ns + self._sensor_period_ns
            self.publish_sensors(stamp)
        if len(self.sim.events) > self._events_reported or time_ns >= self._next_diagnostics_ns:
            self.publish_diagnostics()

    def publish_sensors(self, stamp):
        truth = self.sim.state
        if self.tf_pub is not None:
            self.tf_pub.publish(TFMessage(transforms=[conversions.state_to_transform(truth, stamp)]))
        self.imu_pub.publish(conversions.state_to_imu(truth, self.sim.specific_force_body_mps2, stamp))
        rotors = JointState(name=self._rotor_names, velocity=self.sim.rotor_speeds_radps.tolist())
        rotors.header.stamp = stamp
        self.rotor_pub.publish(rotors)

    def publish_diagnostics(self):
        sim = self.sim
        statuses = []
        new_events = sim.events[self._events_reported:]
        self._events_reported = len(sim.events)
        self._next_diagnostics_ns = sim.time_ns + int(DIAGNOSTICS_PERIOD_S * 1e9)
        collisions = [e for e in sim.events if e.kind == 'collision']
        if collisions:
            e = collisions[-1]
            statuses.append(diagnostics.status(contract.SIM_STATUS.format('collision'), diagnostics.ERROR,
                                               f'collision {len(collisions)}: within {sim.robot_radius_m} m '
                                               'of an obstacle', {contract.COLLISION_TIME_S: repr(collisions[0].time_s),
                                                                   'collisions': len(collisions), **_place(e)}))
        failsafe = [e for e in sim.events if e.kind in ('failsafe', 'failsafe_cleared', 'disarmed')]
        if sim.failsafe_active or any(e.kind == 'failsafe' for e in new_events):
            e = failsafe[-1]
            statuses.append(diagnostics.status(contract.SIM_FAILSAFE, diagnostics.ERROR,
                                               f'setpoint lost: landing failsafe ({e.kind})',
                                               {contract.FAILSAFE_TIME_S: repr(e.time_s), **_place(e)}))
        saturated = sim.saturation or any(e.kind == 'saturation' for e in new_events)
        statuses.append(diagnostics.status(
            contract.SIM_STATUS.format('saturation'), diagnostics.WARN if saturated else diagnostics.OK,
            f'rotor limits reduced {", ".join(sim.saturation) or "the command"}' if saturated else 'within limits',
            {'saturated_steps': sim.saturated_steps}))
        if sim.stopped is not None:
            statuses.append(diagnostics.status(contract.SIM_STATUS.format('stopped'), diagnostics.ERROR,
                                               str(sim.stopped), {'reason': sim.stopped.reason,
                                                                  contract.STOP_TIME_S: repr(sim.stopped.time_s)}))
        statuses.append(diagnostics.status(
            contract.SIM_PUBLISHED, diagnostics.OK, 'distinct odom and /clock steps published (a bag '
            'is checked against it)',
            {'steps': self.steps_published, 'future_setpoints_refused': self.future_setpoints}))
        rtf = self.real_time_factor()
        statuses.append(diagnostics.status(contract.SIM_STATUS.format('real_time_factor'), diagnostics.OK,
                                           f'{rtf:.2f}x', {'rtf': f'{rtf:.3f}'}))
        self.diag_pub.publish(diagnostics.array(stamp_of(sim.time_ns), statuses))

    def real_time_factor(self) -> float:
        wall_s = time.monotonic() - self._wall_start_s
        return (self.sim.time_ns - self._sim_start_ns) * 1e-9 / wall_s if wall_s > 0 else 0.0

    def advance(self, steps):
        if self.sim.stopped is not None:
            return
        try:
            self.sim.advance_steps(steps)
        except SimulationStopped as exc:
            self._report_stop(exc)

    def _report_stop(self, exc):
        self.get_logger().error(str(exc))
        self.publish_diagnostics()

    # --- modes -------------------------------------------------------------------------------------------

    def running(self) -> bool:
        return rclpy.ok(context=self.context) and not self.stop_requested()

    def run_lockstep(self, executor):
        """The lockstep loop (see the module docstring); returns when rclpy shuts down or a stop is requested."""
        lag_ns = lockstep.FOLLOWER_LAG_STEPS * self.steps_per_period * self.sim.step_ns
        while self.running():
            self.publish_step()
            t_k = self.sim.time_ns
            self._await_followers(executor, max(t_k - lag_ns, 0))  # every follower has step 0 before step 1
            now = time.monotonic()
            # before the first setpoint a controller on the graph may have answered before it was matched (its
            # answer lost): advance after STARTUP_REPUBLISH_S, its next tick answers
            timeout_s = self.params['lockstep_timeout_s'] if self.setpoints_received else min(
                self.params['lockstep_timeout_s'], STARTUP_REPUBLISH_S)
            if self.controller_lost:  # one step per LOST_STEP_TIMEOUT_S: a controller that is only slow catches up
                timeout_s = min(timeout_s, LOST_STEP_TIMEOUT_S)
            deadline, republish_at = now + timeout_s, now + STARTUP_REPUBLISH_S
            while self.setpoint_stamp_ns < t_k and self.running():
                now = time.monotonic()
                if now >= deadline:
                    if self.setpoints_received > 0 and not self.controller_lost:
                        self.controller_lost = True
                        self.get_logger().warn(
                            f'no setpoint for t = {t_k * 1e-9:.3f} s within lockstep_timeout_s: each step now waits '
                            f'{LOST_STEP_TIMEOUT_S} s at most (the failsafe lands the vehicle) until one arrives')
                    break
                if self.setpoints_received == 0 and now >= republish_at:  # for nodes that joined late
                    self.publish_step()
                    republish_at = now + STARTUP_REPUBLISH_S
                executor.spin_once(timeout_sec=min(deadline, republish_at) - now)
            if self.sim.time_ns != t_k:  # reset while waiting
                continue
            if not self.running():
                break
            if self.setpoint_stamp_ns >= t_k or self.setpoints_received > 0 or self._controller_present():
                self.advance(self.steps_per_period)
        self.drain(executor)

    def _await_followers(self, executor, stamp_ns, timeout_s=None):
        """Spin until every follower has acknowledged odometry stamped >= stamp_ns (a warning every
        FOLLOWER_WARN_S naming the ones behind); False if timeout_s (wall) passed or a stop came first."""
        start = warned = republished = time.monotonic()
        while (behind := self.followers_behind(stamp_ns)):
            now = time.monotonic()
            if self.setpoints_received == 0 and now - republished >= STARTUP_REPUBLISH_S:  # followers joining late
                self.publish_step()
                republished = now
            if timeout_s is not None and now - start > timeout_s or not rclpy.ok(context=self.context):
                return False
            if timeout_s is None and self.stop_requested():
                return False
            if now - warned > FOLLOWER_WARN_S:
                warned = now
                self.get_logger().warn(f'waiting for {", ".join(behind)} to take odometry of t = '
                                       f'{stamp_ns * 1e-9:.3f} s (lockstep_followers)')
            executor.spin_once(timeout_sec=0.05)
        return True

    def drain(self, executor):
        """At a stop: the final counts on diagnostics, then wait for the followers to take the last step, so a
        recorder stopped after the simulator holds everything it published (what is still in this process's
        writers is lost when it exits). However slow a follower is, the wait goes on while its acknowledgements
        advance; it ends when one made no progress for DRAIN_STALL_S or left the graph (fly's stop ladder,
        SIGTERM then SIGKILL, bounds it too)."""
        if not rclpy.ok(context=self.context):
            return
        self.publish_diagnostics()
        last = self.last_odom_ns
        acked, progress_s = dict(self.acked_ns), time.monotonic()
        while (behind := self.followers_behind(last)) and rclpy.ok(context=self.context):
            now = time.monotonic()
            if self.acked_ns != acked:
                acked, progress_s = dict(self.acked_ns), now
            gone = [f for f in behind if self.count_publishers(lockstep.ack_topic(f)) == 0]
            if gone or now - progress_s > DRAIN_STALL_S:
                why = 'left the graph' if gone else f'acknowledged nothing new for {DRAIN_STALL_S} s'
                self.get_logger().warn(f'{", ".join(gone or behind)} {why} before taking the last odometry '
                                       f'(t = {last * 1e-9:.3f} s): the bag may miss the last steps')
                return
            executor.spin_once(timeout_sec=0.05)

    def _controller_present(self) -> bool:
        """A setpoint publisher that also listens to odom and /clock is on the graph (it may not tick at t = 0)."""
        return (self.count_publishers(contract.SETPOINT) > 0 and self.count_subscribers(contract.ODOM) > 0
                and self.count_subscribers(contract.CLOCK) > 0)

    def start_realtime(self):
        period_s = 1.0 / self.params['odom_rate_hz']
        self._last_wall_s = time.monotonic()
        self._target_ns = float(self.sim.time_ns)
        self.hot_timers.append(self.create_timer(period_s, self._realtime_tick, clock=self._wall))
        self.publish_step()

    def _realtime_tick(self):
        now = time.monotonic()
        self._target_ns += (now - self._last_wall_s) * self.params['rtf'] * 1e9
        self._last_wall_s = now
        steps = int((self._target_ns - self.sim.time_ns) // self.sim.step_ns)
        if steps > 0:
            self.advance(steps)
        self.publish_step()


def _place(event) -> dict:
    """Where an event happened (its time is the contract's *_time_s key, at full precision)."""
    return {'x': f'{event.position[0]:.3f}', 'y': f'{event.position[1]:.3f}',
            'z': f'{event.position[2]:.3f}', **event.detail}


def _spin(node, executor):
    if node.params['mode'] == 'lockstep':
        node.run_lockstep(executor)
    else:
        node.start_realtime()
        while node.running():
            executor.spin_once(timeout_sec=0.1)


def main(args=None):
    run_node(NAME, SimNode, refused=(ValueError, SimulationStopped),
             make_executor=lambda node: HotPathExecutor(lambda: (node.hot_subscriptions, node.hot_timers)),
             spin=_spin, args=args, own_signals=True)


if __name__ == '__main__':
    main()
