"""sim_node: the simulated vehicle on the ROS graph (docs/quad_sim.md).

lockstep: at sim time t_k publish odom (stamp t_k), then /clock (t_k); wait for a cmd/attitude_thrust stamped
>= t_k or lockstep_timeout_s of wall time; advance lockstep_period_s holding that setpoint. After such a timeout
each step waits LOST_STEP_TIMEOUT_S at most until a setpoint arrives again, and not at all while no setpoint
publisher is left (a dead controller: the failsafe lands the vehicle in seconds, not one step per timeout; a
controller that was only slow catches up). Until the first
setpoint arrives, step k is re-published every 0.1 s (for nodes that join late), and the timeout advances
only when a controller (a cmd/attitude_thrust publisher with odom and /clock subscribers) is on the graph:
start-up order does not matter, and a controller whose first tick is after t = 0 still starts the run.
Followers (lockstep_followers, quad_common.lockstep): each step also waits, without a timeout, until every
follower has acknowledged odometry within FOLLOWER_LAG_STEPS of it, so a recorder that falls behind slows the run
instead of losing samples; on SIGINT/SIGTERM the loop stops advancing, publishes its final counts on diagnostics
and waits for the followers to acknowledge its last step (as long as they make progress: DRAIN_STALL_S).
A setpoint stamped more than one period ahead of sim time is refused (counted, warned): taken as "the newest",
it would make every later, correctly stamped one look old.
realtime: a wall-clock timer at odom_rate_hz advances the simulation to rtf * elapsed wall time; each vehicle is
held where it starts (time runs, no physics) until its first setpoint, and its vehicle/engaged goes true only then:
a controller that comes late (its /clock late) finds the vehicle where it started, and re-bases a plan whose start
has passed to its engagement.
fleet (vehicle_names set): one Simulator per named vehicle, each with its topics under its name (cf1/odom,
cf1/cmd/attitude_thrust, ... and its frame cf1/base_link), stepped together under one /clock: step k waits for
every vehicle's setpoint (each vehicle's controller by the rules above), vehicle-vehicle contacts (robot radii)
are events like obstacle collisions (quad_sim.vehicle_contact), and a vehicle whose controller died lands by its
own failsafe while the others fly on. duration_s > 0 ends the run at that sim time (drained as on SIGINT).
"""

import math
import time

import rclpy
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
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
from quad_sim import lockstep_policy
from quad_sim.disturbances import load_profile
from quad_sim.lockstep_policy import LOST_STEP_TIMEOUT_S, STARTUP_REPUBLISH_S
from quad_sim.mocap import MocapConfig, MotionCapture
from quad_sim.simulator import PHYSICS_RATE_HZ, SimulationStopped, Simulator
from quad_sim.vehicle_contact import VEHICLE_COLLISION, VehicleContacts

NAME = 'sim_node'
DIAGNOSTICS_PERIOD_S = 1.0  # sim time
DRAIN_STALL_S = 30.0        # wall time, at shutdown, a follower may go without acknowledging anything new
FOLLOWER_WARN_S = 5.0       # wall time waiting for a follower before each warning naming it
ROTOR_NAMES = [f'rotor_{i}' for i in range(4)]

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
    Param('vehicle_names', Parameter.Type.STRING_ARRAY, 'fleet: the vehicles, each with its topics under its name '
          '(cf1/odom, ...); empty: one vehicle, topics in the node\'s namespace', read_only=True),
    Param('vehicle_files', Parameter.Type.STRING_ARRAY, 'fleet: each vehicle\'s vehicle file; empty: `vehicle` for '
          'all', read_only=True),
    Param('initial_positions', Parameter.Type.DOUBLE_ARRAY, 'fleet: [x, y, z] of each vehicle, flat (m)',
          read_only=True),
    Param('robot_radii_m', Parameter.Type.DOUBLE_ARRAY, 'fleet: each vehicle\'s collision radius (m); empty: '
          'robot_radius_m for all', min=0.0, max=5.0, read_only=True),
    Param('duration_s', 0.0, 'lockstep: end the run (drained, exit 0) at this sim time; 0: run until stopped',
          min=0.0, max=1e6, read_only=True),
    Param('lockstep_followers', '', 'lockstep: comma-separated node names whose acknowledgements each step waits for '
          '(quad_common.lockstep; e.g. recorder): nothing they record is lost', read_only=True),
    Param('mocap_rate_hz', 0.0, 'motion-capture stand-in (quad_sim.mocap) on external/pose: frames per second of sim '
          'time, at most one per step; 0: off', min=0.0, max=10000.0, read_only=True),
    Param('mocap_position_noise_m', 0.0, 'mocap: position noise, RMS per axis (m)', min=0.0, max=10.0,
          read_only=True),
    Param('mocap_attitude_noise_rad', 0.0, 'mocap: attitude noise, RMS per body axis (rad)', min=0.0, max=1.0,
          read_only=True),
    Param('mocap_latency_s', 0.0, 'mocap: sim time from the instant measured (the stamp) to publication (s)',
          min=0.0, max=10.0, read_only=True),
    Param('mocap_dropout_probability', 0.0, 'mocap: probability that a burst of lost frames starts at a frame',
          min=0.0, max=1.0, read_only=True),
    Param('mocap_dropout_burst_s', 0.0, 'mocap: a burst\'s length after its first lost frame (s); 0: one frame',
          min=0.0, max=60.0, read_only=True),
]

MOCAP_FIELDS = ('rate_hz', 'position_noise_m', 'attitude_noise_rad', 'latency_s', 'dropout_probability',
                'dropout_burst_s')  # MocapConfig's, each the parameter mocap_<field>



def stamp_of(time_ns: int) -> Time:
    return Time(sec=time_ns // 1_000_000_000, nanosec=time_ns % 1_000_000_000)


class SimulatedVehicle:
    """One vehicle of the simulator node: its Simulator, its topics (relative names after `prefix`: '' in the
    node's namespace, 'cf1/' for a fleet vehicle) and its lockstep bookkeeping."""

    def __init__(self, node, name: str, sim: Simulator, prefix: str, pace):
        c = contract
        self.node, self.name, self.sim, self.prefix = node, name, sim, prefix
        self.odom_topic, self.setpoint_topic = prefix + c.ODOM, prefix + c.SETPOINT
        self.body_frame = prefix + contract.BODY_FRAME
        self.odom_pub = node.create_publisher(Odometry, self.odom_topic, pace(c.ODOM))
        self.imu_pub = node.create_publisher(Imu, prefix + c.IMU, pace(c.IMU))
        self.rotor_pub = node.create_publisher(JointState, prefix + c.ROTOR_SPEEDS, pace(c.ROTOR_SPEEDS))
        self.diag_pub = node.create_publisher(DiagnosticArray, prefix + c.DIAGNOSTICS, pace(c.DIAGNOSTICS))
        # lockstep: the simulated vehicle flies our setpoints from the start (a bridge says so only during a
        # hand-over); realtime: from its first setpoint on (held until then), so a plan whose start passed while
        # the controller was still starting begins where the vehicle is (quad_control.loop's engagement)
        self.engaged_pub = node.create_publisher(Bool, prefix + c.ENGAGED, c.qos(c.ENGAGED))
        self.held_until_setpoint = node.params['mode'] == 'realtime'
        if not self.held_until_setpoint:
            self.engaged_pub.publish(Bool(data=True))
        self.setpoint_sub = node.create_subscription(Imu, self.setpoint_topic, self._on_setpoint,
                                                     c.qos(c.SETPOINT), raw=True)
        self.reference_sub = None
        if node.params['max_tracking_error_m'] > 0:
            self.reference_sub = node.create_subscription(MultiDOFJointTrajectory, prefix + c.REFERENCE,
                                                          self._on_reference, c.qos(c.REFERENCE))
        self._odom_packer = cdr.OdometryPacker(child_frame_id=self.body_frame)
        self.mocap = MotionCapture(node.mocap_config, seed=sim.seed) if node.mocap_config.enabled else None
        self.mocap_pub = (node.create_publisher(PoseStamped, prefix + c.EXTERNAL_POSE, c.qos(c.EXTERNAL_POSE))
                          if self.mocap else None)
        self.reset_bookkeeping()

    def reset_bookkeeping(self):
        self.setpoint_stamp_ns = -1
        self.setpoints_received = 0
        self.future_setpoints = 0
        self.controller_lost = False  # a setpoint missed lockstep_timeout_s: steps wait LOST_STEP_TIMEOUT_S at most
        self.steps_published = 0  # distinct odom (and /clock) stamps published
        self.last_odom_ns = -1
        self.events_reported = 0
        self.next_diagnostics_ns = 0
        self.next_sensors_ns = 0
        if self.mocap is not None:
            self.mocap.reset()

    def _log(self):
        return self.node.get_logger()

    def _on_setpoint(self, raw: bytes):
        """cmd/attitude_thrust, serialized (quad_common.cdr: the tick's critical path)."""
        stamp_ns = cdr.header_stamp_ns(raw, Imu)
        verdict = lockstep_policy.classify_setpoint(stamp_ns, self.setpoint_stamp_ns, self.sim.time_ns,
                                                    self.node.steps_per_period * self.sim.step_ns)
        if verdict == lockstep_policy.OLDER:
            return
        if verdict == lockstep_policy.FUTURE:
            self.future_setpoints += 1
            self._log().warn(
                f'{self.prefix}setpoint refused: stamped {stamp_ns * 1e-9:.3f} s, ahead of sim time '
                f'{self.sim.time_s:.3f} s by more than one period ({self.future_setpoints} so far; a clock other '
                'than /clock?)', throttle_duration_sec=1.0)
            return
        try:
            setpoint = cdr.imu_to_setpoint(raw)
            self.sim.set_setpoint(setpoint)
        except ValueError as exc:
            self._log().warn(f'{self.prefix}setpoint refused: {exc}', throttle_duration_sec=1.0)
            return
        self.setpoint_stamp_ns = stamp_ns
        self.setpoints_received += 1
        self.controller_lost = False
        if self.held_until_setpoint and self.setpoints_received == 1:
            self._log().info(f'{self.prefix}first setpoint at t = {self.sim.time_s:.3f} s: the vehicle flies '
                             '(held until now)')
            self.engaged_pub.publish(Bool(data=True))

    def _on_reference(self, msg: MultiDOFJointTrajectory):
        if msg.points and msg.points[0].transforms and self.sim.stopped is None:
            try:
                self.sim.check_tracking(conversions.vec3(msg.points[0].transforms[0].translation),
                                        self.node.params['max_tracking_error_m'])
            except SimulationStopped as exc:
                self.report_stop(exc)

    def report_stop(self, exc):
        self._log().error(f'{self.name + ": " if self.prefix else ""}{exc}')
        self.publish_diagnostics()

    def has_setpoint_publisher(self) -> bool:
        return self.node.count_publishers(self.setpoint_topic) > 0

    def controller_present(self) -> bool:
        """A setpoint publisher that also listens to odom and /clock is on the graph (it may not tick at t = 0)."""
        n = self.node
        return (n.count_publishers(self.setpoint_topic) > 0 and n.count_subscribers(self.odom_topic) > 0
                and n.count_subscribers(contract.CLOCK) > 0)

    def publish_odometry(self, time_ns: int):
        self.odom_pub.publish(self._odom_packer.pack(self.sim.odometry_state(), time_ns))
        if time_ns != self.last_odom_ns:  # the first step is re-published until a setpoint comes: one step
            self.steps_published += 1
        self.last_odom_ns = time_ns

    def publish_after_clock(self, time_ns: int, stamp):
        """Every 1 / sensor_rate_hz of sim time /tf, imu and rotor_speeds; diagnostics on an event or each
        DIAGNOSTICS_PERIOD_S."""
        if time_ns >= self.next_sensors_ns:
            self.next_sensors_ns = time_ns + self.node.sensor_period_ns
            self.publish_sensors(stamp)
        if self.mocap is not None:
            self.publish_mocap(time_ns)
        if len(self.sim.events) > self.events_reported or time_ns >= self.next_diagnostics_ns:
            self.publish_diagnostics()

    def publish_sensors(self, stamp):
        """/tf, imu and rotor_speeds, each only while something subscribes to it (building them is most of their
        cost: a fleet's vehicles publish them to nobody)."""
        truth = self.sim.state
        tf_pub = self.node.tf_pub
        if tf_pub is not None and tf_pub.get_subscription_count():
            tf_pub.publish(TFMessage(transforms=[conversions.state_to_transform(
                truth, stamp, child_frame_id=self.body_frame)]))
        if self.imu_pub.get_subscription_count():
            self.imu_pub.publish(conversions.state_to_imu(truth, self.sim.specific_force_body_mps2, stamp,
                                                          frame_id=self.body_frame))
        if self.rotor_pub.get_subscription_count():
            rotors = JointState(name=ROTOR_NAMES, velocity=self.sim.rotor_speeds_radps.tolist())
            rotors.header.stamp = stamp
            self.rotor_pub.publish(rotors)

    def publish_mocap(self, time_ns: int):
        """external/pose: the mocap frames delivered by now, each stamped with the instant it measured the truth
        (quad_sim.mocap), in the world frame."""
        for frame in self.mocap.offer(time_ns, self.sim.position_m, self.sim.state.quaternion):
            msg = PoseStamped()
            msg.header.stamp, msg.header.frame_id = stamp_of(frame.stamp_ns), contract.WORLD_FRAME
            msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(v) for v in frame.position)
            msg.pose.orientation = conversions.to_quaternion(frame.quaternion)
            self.mocap_pub.publish(msg)

    def publish_diagnostics(self):
        sim = self.sim
        statuses = []
        new_events = sim.events[self.events_reported:]
        self.events_reported = len(sim.events)
        self.next_diagnostics_ns = sim.time_ns + int(DIAGNOSTICS_PERIOD_S * 1e9)
        collisions = [e for e in sim.events if e.kind == 'collision']
        if collisions:
            e = collisions[-1]
            statuses.append(diagnostics.status(contract.SIM_STATUS.format('collision'), diagnostics.ERROR,
                                               f'collision {len(collisions)}: within {sim.robot_radius_m} m '
                                               'of an obstacle', {contract.COLLISION_TIME_S: repr(collisions[0].time_s),
                                                                   'collisions': len(collisions), **_place(e)}))
        contacts = [e for e in sim.events if e.kind == VEHICLE_COLLISION]
        if contacts:
            e = contacts[-1]
            statuses.append(diagnostics.status(contract.SIM_STATUS.format(VEHICLE_COLLISION), diagnostics.ERROR,
                                               f'vehicle collision {len(contacts)}: with {e.detail["other"]}',
                                               {contract.COLLISION_TIME_S: repr(contacts[0].time_s),
                                                'collisions': len(contacts), **_place(e)}))
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
        rtf = self.node.real_time_factor()
        statuses.append(diagnostics.status(contract.SIM_STATUS.format('real_time_factor'), diagnostics.OK,
                                           f'{rtf:.2f}x', {'rtf': f'{rtf:.3f}'}))
        self.diag_pub.publish(diagnostics.array(stamp_of(sim.time_ns), statuses))

    def advance(self, steps):
        if self.sim.stopped is not None:
            return
        try:
            if self.held_until_setpoint and self.setpoints_received == 0:
                self.sim.hold_steps(steps)   # realtime: time runs (the controller needs /clock), the vehicle waits
            else:
                self.sim.advance_steps(steps)
        except SimulationStopped as exc:
            self.report_stop(exc)


class SimNode(Node):
    def __init__(self, **kwargs):
        super().__init__(NAME, **kwargs)
        self.params = ParameterSet(self, SPECS)
        p = self.params
        world = load_world(self._config(p['world'], 'world')) if p['world'] else None
        profile = load_profile(self._config(p['disturbances_file'], 'disturbances_file'), p['disturbances'])
        fleet = _fleet_layout(p)
        self.mocap_config = MocapConfig(**{f: p[f'mocap_{f}'] for f in MOCAP_FIELDS})
        sims = []
        files_param = 'vehicle_files' if p['vehicle_files'] else 'vehicle'
        for k, (_, vehicle_file, position, radius_m) in enumerate(fleet):
            vehicle = load_vehicle(self._config(vehicle_file, files_param), plant=p['plant'] or None)
            sims.append(Simulator(vehicle, physics_rate_hz=p['physics_rate_hz'], initial_position=position,
                                  initial_yaw=p['initial_yaw'], disturbances=profile, world=world,
                                  robot_radius_m=radius_m, seed=(p['seed'] + k) % 2**31,
                                  setpoint_timeout_s=p['setpoint_timeout_s']))
        self.sim = sims[0]   # the time base: every vehicle's simulator is stepped with it
        self.sim.warm_up()
        try:
            self.steps_per_period = self.sim.steps_in(p['lockstep_period_s'])
        except ValueError as exc:
            raise ValueError(f'lockstep_period_s: {exc}') from None
        self.followers = [f.strip() for f in p['lockstep_followers'].split(',') if f.strip()]
        c = contract
        pace = (lambda topic: lockstep.PACED) if self.followers else c.qos  # followers: paced, deep history
        self.clock_pub = self.create_publisher(ClockMsg, c.CLOCK, pace(c.CLOCK))
        self.tf_pub = self.create_publisher(TFMessage, c.TF, c.qos(c.TF)) if TFMessage else None
        if TFMessage is None:
            self.get_logger().warn('tf2_msgs is not installed here: /tf is not published (odom carries the pose)')
        self.sensor_period_ns = int(round(1e9 / p['sensor_rate_hz'])) if p['sensor_rate_hz'] > 0 else 0
        named = bool(p['vehicle_names'])
        self.vehicles = [SimulatedVehicle(self, name, sim, f'{name}/' if named else '', pace)
                         for (name, *_), sim in zip(fleet, sims)]
        self.contacts = VehicleContacts([v.name for v in self.vehicles], sims, [r for *_, r in fleet])
        self.hot_subscriptions = [v.setpoint_sub for v in self.vehicles]
        self.acked_ns = dict.fromkeys(self.followers, -1)
        for follower in self.followers:
            self.hot_subscriptions.append(self.create_subscription(
                ClockMsg, lockstep.ack_topic(follower),
                lambda msg, f=follower: self._on_ack(f, msg), lockstep.ACK))
        self.stop_requested = lambda: False  # main() replaces it with its signal flag
        self.hot_subscriptions += [v.reference_sub for v in self.vehicles if v.reference_sub is not None]
        self.hot_timers = []
        self.create_service(Trigger, 'reset', self._on_reset)
        self._wall = Clock(clock_type=ClockType.STEADY_TIME)
        self._reset_bookkeeping()
        what = (f'{sims[0].vehicle.name} at {list(fleet[0][2])}' if not named else
                f'{len(sims)} vehicles ({", ".join(v.name for v in self.vehicles)})')
        self.get_logger().info(
            f'{p["mode"]}: {what}, {p["physics_rate_hz"]:g} Hz physics, '
            f'disturbances {profile.name}, world {p["world"] or "none"}')

    def hot_entities(self):
        """The lockstep's per-step entities (quad_common.hot_path): every vehicle's setpoints, the followers'
        acknowledgements, the realtime tick."""
        return self.hot_subscriptions, self.hot_timers

    def _config(self, path, name):
        try:
            return resolve_config(path)
        except FileNotFoundError as exc:
            raise ValueError(f'{name} = {path!r}: {exc}') from None

    def _reset_bookkeeping(self):
        for v in self.vehicles:
            v.reset_bookkeeping()
        self.contacts.reset()
        self._wall_start_s = time.monotonic()
        self._sim_start_ns = self.sim.time_ns
        self._first_advance = None    # (wall s, sim ns) of the first step advanced
        self._longest = {}            # kind -> (the longest wait s while stepping, at t ns, who it waited for)

    # --- the single vehicle's view (one vehicle: the node's own topics) ------------------------------------

    @property
    def setpoints_received(self) -> int:
        return min(v.setpoints_received for v in self.vehicles)

    @property
    def future_setpoints(self) -> int:
        return sum(v.future_setpoints for v in self.vehicles)

    @property
    def steps_published(self) -> int:
        return self.vehicles[0].steps_published

    @property
    def last_odom_ns(self) -> int:
        return self.vehicles[0].last_odom_ns

    # --- inputs ------------------------------------------------------------------------------------------

    def _on_ack(self, follower: str, msg: ClockMsg):
        self.acked_ns[follower] = max(self.acked_ns[follower], msg.clock.sec * 1_000_000_000 + msg.clock.nanosec)

    def followers_behind(self, stamp_ns: int) -> list[str]:
        """Followers whose newest acknowledged odometry is older than `stamp_ns`."""
        return [f for f, acked in self.acked_ns.items() if acked < stamp_ns]

    def _on_reset(self, request, response):
        for v in self.vehicles:
            v.sim.reset()
        self._reset_bookkeeping()
        response.success, response.message = True, 'simulation reset to its initial state; time restarts at 0'
        self.get_logger().info(response.message)
        return response

    # --- outputs -----------------------------------------------------------------------------------------

    def publish_step(self, vehicles=None):
        """Every vehicle's odom and then /clock at the current sim time (contract order); then its sensors and
        diagnostics when due (after /clock: the controller's tick does not wait for them). vehicles: only these
        odometries (a re-publication for controllers that joined late). Realtime: /clock first, as no tick waits
        for odometry there, and an odom that arrives before its /clock is ahead of the controller's clock by a
        tick's worth of sim time (more than one period at rtf > 1 or a late tick): refused."""
        time_ns = self.sim.time_ns
        stamp = stamp_of(time_ns)
        clock_first = self.params['mode'] == 'realtime'
        if clock_first:
            self.clock_pub.publish(ClockMsg(clock=stamp))
        for v in self.vehicles if vehicles is None else vehicles:
            v.publish_odometry(time_ns)
        if not clock_first:
            self.clock_pub.publish(ClockMsg(clock=stamp))
        for v in self.vehicles:
            v.publish_after_clock(time_ns, stamp)

    def publish_diagnostics(self):
        for v in self.vehicles:
            v.publish_diagnostics()

    def real_time_factor(self) -> float:
        wall_s = time.monotonic() - self._wall_start_s
        return (self.sim.time_ns - self._sim_start_ns) * 1e-9 / wall_s if wall_s > 0 else 0.0

    def advance(self, steps):
        t0_s = self.sim.time_s
        if self._first_advance is None:
            self._first_advance = (time.monotonic(), self.sim.time_ns, time.process_time())
        for v in self.vehicles:
            v.advance(steps)
        if len(self.vehicles) > 1:
            self.contacts.step(t0_s, steps * self.sim.step_ns * 1e-9)

    # --- modes -------------------------------------------------------------------------------------------

    def running(self) -> bool:
        return rclpy.ok(context=self.context) and not self.stop_requested()

    def _ended(self) -> bool:
        end_s = self.params['duration_s']
        return end_s > 0 and self.sim.time_s >= end_s - 1e-9

    def run_lockstep(self, executor):
        """The lockstep loop (see the module docstring); returns when rclpy shuts down, a stop is requested or
        duration_s is reached."""
        lag_ns = lockstep.FOLLOWER_LAG_STEPS * self.steps_per_period * self.sim.step_ns
        while self.running():
            self.publish_step()
            t_k = self.sim.time_ns
            follower_ns = max(t_k - lag_ns, 0)   # every follower has step 0 before step 1
            waited, behind = time.monotonic(), self.followers_behind(follower_ns)
            self._await_followers(executor, follower_ns)
            now = time.monotonic()
            self._longest_wait('followers', now - waited, t_k, behind)
            if self._ended():
                break
            waiting = self._await_setpoints(executor, t_k)
            self._longest_wait('setpoints', time.monotonic() - now, t_k, [v.name for v in waiting])
            if self.sim.time_ns != t_k:  # reset while waiting
                continue
            if not self.running():
                break
            if lockstep_policy.may_advance(((v.setpoint_stamp_ns, v.setpoints_received, v.controller_present)
                                            for v in self.vehicles), t_k):
                self.advance(self.steps_per_period)
        if self._first_advance is not None:
            wall_s = time.monotonic() - self._first_advance[0]
            sim_s = (self.sim.time_ns - self._first_advance[1]) * 1e-9
            self.get_logger().info(f'lockstep: stepped {sim_s:.3f} s of {len(self.vehicles)} vehicle(s) in '
                                   f'{wall_s:.3f} s ({sim_s / max(wall_s, 1e-9):.2f}x real time; this process '
                                   f'{time.process_time() - self._first_advance[2]:.3f} s of CPU)')
            for what, (wait_s, t_ns, who) in self._longest.items():
                self.get_logger().info(f'lockstep: longest wait for {what} {wait_s * 1e3:.1f} ms at t = '
                                       f'{t_ns * 1e-9:.3f} s ({", ".join(who) or "none behind at its start"})')
        self.drain(executor)

    def _longest_wait(self, what: str, wait_s: float, t_ns: int, who):
        """Keeps the longest wall-time wait of each kind while stepping (logged at the end: where a slow run lost
        its time)."""
        if self._first_advance is not None and wait_s > self._longest.get(what, (0.0,))[0]:
            self._longest[what] = (wait_s, t_ns, list(who))

    def _await_setpoints(self, executor, t_k: int) -> list:
        """Spin until every vehicle has a setpoint stamped >= t_k or its wait ran out: lockstep_timeout_s; before
        its first setpoint STARTUP_REPUBLISH_S at most (its odometry re-published each time, for controllers that
        joined late or answered before they were matched); once one was missed, LOST_STEP_TIMEOUT_S at most.
        Returns the vehicles it waited for (those without one at its start)."""
        now = time.monotonic()
        deadlines = {v: now + lockstep_policy.setpoint_timeout_s(
            self.params['lockstep_timeout_s'], v.setpoints_received, v.controller_lost,
            v.controller_lost and v.has_setpoint_publisher()) for v in self.vehicles}
        waited_for = [v for v in self.vehicles if v.setpoint_stamp_ns < t_k]
        wait = lockstep_policy.SetpointWait(waited_for, deadlines, now)
        while wait.waiting and self.running():
            now = time.monotonic()
            for v in wait.expire(now):
                if v.setpoints_received > 0 and not v.controller_lost:
                    v.controller_lost = True
                    self.get_logger().warn(
                        f'{v.name}: ' * bool(v.prefix) + f'no setpoint for t = {t_k * 1e-9:.3f} s within '
                        f'lockstep_timeout_s: each step now waits {LOST_STEP_TIMEOUT_S} s at most (the failsafe '
                        'lands the vehicle) until one arrives')
            if not wait.waiting:
                break
            starting = [v for v in wait.waiting if v.setpoints_received == 0]
            if starting and wait.republish_due(now):  # for nodes that joined late
                self.publish_step(starting)
            executor.spin_once(timeout_sec=wait.wake_in_s(now))
            wait.answered(lambda v: v.setpoint_stamp_ns >= t_k)
        return waited_for

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


def _fleet_layout(p) -> list[tuple]:
    """(name, vehicle file, initial position, robot radius) per vehicle: one from `vehicle`, `initial_position`
    and `robot_radius_m`, or the fleet's from vehicle_names and its per-vehicle arrays (each checked: its length,
    names a ROS name component can take, no name twice)."""
    names = p['vehicle_names']
    if not names:
        return [('', p['vehicle'], list(p['initial_position']), p['robot_radius_m'])]
    n = len(names)
    for name in names:
        if not contract.is_vehicle_name(name):
            raise ValueError(f'vehicle_names: {name!r} refused: {contract.VEHICLE_NAME_RULE}')
        if names.count(name) > 1:
            raise ValueError(f'vehicle_names: {name!r} refused: named twice')
    files = p['vehicle_files'] or [p['vehicle']] * n
    positions = p['initial_positions']
    radii = p['robot_radii_m'] or [p['robot_radius_m']] * n
    for field, values, size in (('vehicle_files', files, n), ('initial_positions', positions, 3 * n),
                                ('robot_radii_m', radii, n)):
        if len(values) != size:
            raise ValueError(f'{field} = {list(values)!r} refused: needs {size} values '
                             f'for the {n} vehicles of vehicle_names')
    return [(name, files[k], [float(x) for x in positions[3 * k:3 * k + 3]], float(radii[k]))
            for k, name in enumerate(names)]


def _place(event) -> dict:
    """Where an event happened (its time is the contract's *_time_s key, at full precision)."""
    return {'x': f'{event.position[0]:.3f}', 'y': f'{event.position[1]:.3f}',
            'z': f'{event.position[2]:.3f}', **event.detail}


def spin(node, executor):
    """The simulator's loop: lockstep, or realtime paced by its wall-clock tick."""
    if node.params['mode'] == 'lockstep':
        node.run_lockstep(executor)
    else:
        node.start_realtime()
        while node.running():
            executor.spin_once(timeout_sec=0.1)


def main(args=None):
    run_node(NAME, SimNode, refused=(ValueError, SimulationStopped),
             make_executor=lambda node: HotPathExecutor(node.hot_entities),
             spin=spin, args=args, own_signals=True)


if __name__ == '__main__':
    main()
