"""One simulated vehicle on sim_node's graph: its Simulator, its topics (odom, imu, rotor_speeds, diagnostics,
vehicle/engaged, external/pose; cmd/attitude_thrust and control/reference in) and its lockstep bookkeeping
(quad_sim.lockstep_policy.VehicleLockstep). sim_node steps every vehicle under one /clock."""

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Bool
from trajectory_msgs.msg import MultiDOFJointTrajectory

try:  # not among the PyPI ROS wheels; present on every machine with ROS 2 installed
    from tf2_msgs.msg import TFMessage
except ImportError:
    TFMessage = None

from quad_common import contract, conversions, diagnostics
from quad_common.ros import cdr
from quad_sim import lockstep_policy as policy
from quad_sim.mocap import MotionCapture
from quad_sim.sim_diagnostics import ReportSchedule, vehicle_statuses
from quad_sim.simulator import SimulationStopped, Simulator

ROTOR_NAMES = [f'rotor_{i}' for i in range(4)]

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
        self.lockstep = policy.VehicleLockstep()
        self.schedule = ReportSchedule(self.node.sensor_period_ns)
        if self.mocap is not None:
            self.mocap.reset()

    def _log(self):
        return self.node.get_logger()

    def _on_setpoint(self, raw: bytes):
        """cmd/attitude_thrust, serialized (quad_common.ros.cdr: the tick's critical path)."""
        stamp_ns = cdr.header_stamp_ns(raw, Imu)
        verdict = self.lockstep.classify(stamp_ns, self.sim.time_ns, self.node.steps_per_period * self.sim.step_ns)
        if verdict == policy.OLDER:
            return
        if verdict == policy.FUTURE:
            self._log().warn(
                f'{self.prefix}setpoint refused: stamped {stamp_ns * 1e-9:.3f} s, ahead of sim time '
                f'{self.sim.time_s:.3f} s by more than {policy.FUTURE_LIMIT_PERIODS} period(s) '
                f'({self.lockstep.future_setpoints} so far; a clock other than /clock?)', throttle_duration_sec=1.0)
            return
        try:
            setpoint = cdr.imu_to_setpoint(raw)
            self.sim.set_setpoint(setpoint)
        except ValueError as exc:
            self._log().warn(f'{self.prefix}setpoint refused: {exc}', throttle_duration_sec=1.0)
            return
        if self.lockstep.applied(stamp_ns) and self.held_until_setpoint:
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
        self.lockstep.odometry_published(time_ns)

    def publish_after_clock(self, time_ns: int, stamp):
        """Every 1 / sensor_rate_hz of sim time /tf, imu and rotor_speeds; diagnostics on an event or each
        DIAGNOSTICS_PERIOD_S."""
        if self.schedule.sensors_due(time_ns):
            self.publish_sensors(stamp)
        if self.mocap is not None:
            self.publish_mocap(time_ns)
        if self.schedule.diagnostics_due(time_ns, len(self.sim.events)):
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
        new_events = self.schedule.reported(sim.time_ns, sim.events)
        statuses = vehicle_statuses(sim, new_events, self.lockstep.steps_published, self.lockstep.future_setpoints,
                                    self.node.real_time_factor())
        self.diag_pub.publish(diagnostics.array(stamp_of(sim.time_ns), statuses))

    def advance(self, steps):
        if self.sim.stopped is not None:
            return
        try:
            if self.held_until_setpoint and self.lockstep.setpoints_received == 0:
                self.sim.hold_steps(steps)   # realtime: time runs (the controller needs /clock), the vehicle waits
            else:
                self.sim.advance_steps(steps)
        except SimulationStopped as exc:
            self.report_stop(exc)
