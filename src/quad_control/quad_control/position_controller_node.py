"""position_controller: the fixed-rate position loop (pd | pid | se3 | a user class: quad_control.plugins) between
`odom` and `cmd/attitude_thrust`.

Each tick at node-clock time t samples the latched `trajectory`, runs the controller on the newest
odometry and publishes `cmd/attitude_thrust` and `control/reference`, both stamped t.
lockstep: the tick waits for the odometry stamped >= t (contract: docs/quad_control.md).
Failsafe: stale or non-finite odometry -> no setpoint at all, ERROR on `diagnostics`.
state_source external_pose: `external/pose` (motion capture) takes odometry's place, its velocity from
quad_control.pose_state's filter; every rule above holds for it (its stamp is the odometry's).
The tick never waits for a trajectory: its bytes are decoded on a thread of their own (TrajectoryDecoder) and the
result is swapped in on the executor's thread; odometry stamped more than one period ahead of the node clock is
refused (a node on another clock, or one that ran ahead, must not become "the newest").
"""

import threading
import time
from collections import deque

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import Imu
from std_msgs.msg import Bool
from trajectory_msgs.msg import MultiDOFJointTrajectory

from quad_common import contract, diagnostics, mocap_frames
from quad_common.paths import parameter_file
from quad_common.realtime import apply_or_report, thread_ids
from quad_common.ros import cdr, lockstep
from quad_common.ros.hot_path import HotPathExecutor
from quad_common.ros.hot_path import now_ns as now_ns_of
from quad_common.ros.node_main import run_node
from quad_common.ros.ros_params import ParameterSet
from quad_common.vehicle import load_vehicle
from quad_control.loop import ControlLoop, Tick
from quad_control.parameters import NODE_NAME, SPECS, gains_from
from quad_control.plugins import ControllerRefused, make_controller
from quad_control.pose_state import PoseNotNewer, PoseStateFilter
from quad_control.position import Limits

DIAGNOSTICS_PERIOD_S = 1.0


class TrajectoryDecoder:
    """Decodes serialized trajectories (quad_common.ros.cdr.trajectory_to_sampled) on a thread of its own.

    submit(raw) returns at once; when a result is ready, on_ready() is called from the worker (it triggers a
    guard condition) and take() hands the results, in arrival order, to the executor's thread: the plan is
    swapped into the loop there, atomically between two ticks. A result is ('ok', start_ns, trajectory,
    decode_s) or ('refused', reason).
    """

    def __init__(self, on_ready, decode=cdr.trajectory_to_sampled):
        self.decode = decode
        self._on_ready = on_ready
        self._lock = threading.Condition()
        self._queue, self._results, self._closed = deque(), deque(), False
        self._thread = threading.Thread(target=self._run, name='trajectory-decoder', daemon=True)
        self._thread.start()

    @property
    def native_id(self) -> int:
        """The worker's thread id (the kernel's)."""
        return self._thread.native_id

    def submit(self, raw: bytes):
        with self._lock:
            self._queue.append(raw)
            self._lock.notify()

    def take(self) -> list:
        with self._lock:
            results, self._results = list(self._results), deque()
        return results

    def close(self):
        with self._lock:
            self._closed = True
            self._lock.notify()
        self._thread.join(timeout=5.0)

    def _run(self):
        while True:
            with self._lock:
                self._lock.wait_for(lambda: self._queue or self._closed)
                if self._closed:
                    return
                raw = self._queue.popleft()
            started = time.perf_counter()
            try:
                start_ns, traj = self.decode(raw)
                result = ('ok', start_ns, traj, time.perf_counter() - started)
            except Exception as exc:  # noqa: BLE001  (any undecodable input is refused, the node goes on)
                result = ('refused', f'{type(exc).__name__}: {exc}' if not isinstance(exc, ValueError) else str(exc))
            with self._lock:
                self._results.append(result)
            self._on_ready()


def _stamp(t_ns: int):
    return rclpy.time.Time(nanoseconds=t_ns).to_msg()


class PositionControllerNode(Node):
    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        self.params = ParameterSet(self, SPECS, on_change=self._on_change)
        self.vehicle = load_vehicle(parameter_file('vehicle', self.params['vehicle']))
        self.controller = self._make_controller(self.params.values)
        self.loop = ControlLoop(self.controller, self.params['rate_hz'], lockstep=self.params['lockstep'],
                                wait_for_trajectory=self.params['wait_for_trajectory'],
                                max_start_step_m=self.params['max_start_step_m'],
                                engaged=not self.params['wait_for_engagement'],
                                engage_delay_s=self.params['engage_delay_s'], on_fault=self._fault,
                                on_event=self.get_logger().info)
        self.odom_received_ns = None  # steady time (time.monotonic_ns, CLOCK_MONOTONIC as rcl's steady clock) of
        #                               the newest finite odometry
        self.odom_fault = None      # reason the newest odometry was refused (non-finite), until a good one
        self.pending_since_ns = 0
        self.stale = False
        self.last_error = ''
        self.tick_times_ns = deque(maxlen=4096)
        self.odom_age_ns = [0, 0]     # (sum, count) of tick - odometry stamp since the last diagnostics
        self.node_counts = dict.fromkeys(('odom_timeouts', 'nonfinite_odom', 'future_odom', 'old_poses',
                                          'rejected_trajectories'), 0)
        self.last_future_odom = ''  # 'stamp s > clock s' of the last odometry refused as from the future
        c = contract
        # lockstep: as deep as the simulator's paced topics, so its followers (the recorder) lose no setpoint
        pace = (lambda topic: lockstep.PACED) if self.params['lockstep'] else c.qos
        self.cmd_pub = self.create_publisher(Imu, c.SETPOINT, pace(c.SETPOINT))
        self.ref_pub = self.create_publisher(MultiDOFJointTrajectory, c.REFERENCE, pace(c.REFERENCE))
        self.diag_pub = self.create_publisher(DiagnosticArray, c.DIAGNOSTICS, c.qos(c.DIAGNOSTICS))
        # the state's subscription: odometry, or motion capture's pose (the filter makes the state)
        if self.params['state_source'] == 'external_pose':
            self.pose_filter = PoseStateFilter(self.params['pose_position_noise_m'],
                                               self.params['pose_acceleration_mps2'], self.params['odom_timeout_s'])
            self.state_sub = self.create_subscription(PoseStamped, c.EXTERNAL_POSE, self._on_odom,
                                                     c.qos(c.EXTERNAL_POSE), raw=True)
        else:
            self.pose_filter = None
            self.state_sub = self.create_subscription(Odometry, c.ODOM, self._on_odom, c.qos(c.ODOM), raw=True)
        self.engaged_sub = self.create_subscription(Bool, c.ENGAGED, self._on_engaged, c.qos(c.ENGAGED)) \
            if self.params['wait_for_engagement'] else None
        self._setpoint_packer = cdr.SetpointPacker()
        self._reference_packer = cdr.ReferencePacker()
        self.trajectory_ready = self.create_guard_condition(self._take_trajectories)
        self.trajectory_decoder = TrajectoryDecoder(self.trajectory_ready.trigger)
        self.trajectory_sub = self.create_subscription(MultiDOFJointTrajectory, c.TRAJECTORY,
                                                       self.trajectory_decoder.submit, c.qos(c.TRAJECTORY), raw=True)
        self.timer = self.create_timer(1.0 / self.params['rate_hz'], self._on_tick)
        self._clock_subs = (-1, [])   # (the node's subscription count, its /clock subscription): hot_entities
        self.steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(DIAGNOSTICS_PERIOD_S, self.publish_diagnostics, clock=self.steady)
        # the last: every thread the tick needs exists now (the decoder's bulk work stays ordinary: a 10,000-point
        # plan decoded under SCHED_FIFO would hold a core from everything else on the machine, the bridge included)
        decoder = self.trajectory_decoder.native_id
        self.realtime, self.realtime_refused = apply_or_report(
            self.params['realtime_priority'], self.get_logger().error,
            tids=lambda: [t for t in thread_ids() if t != decoder])
        self.get_logger().info(f"{self.params['controller']} at {self.params['rate_hz']} Hz, "
                               f"lockstep={self.params['lockstep']}, vehicle {self.vehicle.name}, "
                               f"scheduling {self.realtime}")

    def _make_controller(self, values: dict):
        """The controller `values` name (quad_control.plugins.make_controller; a user class is refused there)."""
        return make_controller(values['controller'], gains_from(values), self.vehicle,
                               Limits.of(self.vehicle, values['max_tilt_deg']), rate_hz=values['rate_hz'],
                               wall_clock=not values['lockstep'])

    def hot_entities(self):
        """What a tick needs at once (HotPathExecutor): /clock (use_sim_time), odom, the tick timer, and the
        trajectory's bytes and its decoded result (rare, but a new plan must not wait for the slow pass)."""
        subscriptions = self._subscriptions   # rclpy 7.1 (quad_common.ros.hot_path.CHECKED_RCLPY_VERSION): a list
        if self._clock_subs[0] != len(subscriptions):   # asked before every wait: look up /clock's only when changed
            self._clock_subs = (len(subscriptions), [s for s in subscriptions if s.topic_name == contract.CLOCK])
        clock = self._clock_subs[1]
        engaged = [self.engaged_sub] if self.engaged_sub is not None else []
        return clock + engaged + [self.state_sub, self.trajectory_sub], [self.timer], [self.trajectory_ready]

    def destroy_node(self):
        self.trajectory_decoder.close()
        super().destroy_node()

    @property
    def trajectory(self):
        """The newest accepted plan (start_ns, SampledTrajectory), started or not; None before any."""
        return self.loop.next_plan or self.loop.trajectory

    @property
    def counts(self) -> dict:
        """The loop's counts (setpoints, deferrals, refusals, saturations) and the node's (inputs)."""
        return {**self.loop.counts, **self.node_counts}

    @property
    def pending_tick_ns(self):
        return self.loop.pending_tick_ns

    # --- inputs ---------------------------------------------------------------------------------

    def _pose_of(self, raw: bytes):
        """(stamp ns, ENU position, FLU -> ENU attitude) of a serialized external pose."""
        msg = deserialize_message(raw, PoseStamped)
        p, q = msg.pose.position, msg.pose.orientation
        position, quaternion, _ = mocap_frames.to_enu(self.params['external_pose_frame'], (p.x, p.y, p.z),
                                                      (q.x, q.y, q.z, q.w))
        return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec, position, quaternion

    def _on_odom(self, raw: bytes):
        """The state's message: odom, serialized (quad_common.ros.cdr: the tick's critical path), or external/pose
        (state_source external_pose), made a state by the pose filter once it passed the checks below."""
        pose = None
        try:
            if self.pose_filter is None:
                stamp_ns, state = cdr.odometry_to_state(raw)
                if not state.is_finite():
                    raise ValueError(f'position {state.position.tolist()}, velocity {state.velocity.tolist()}, '
                                     f'body rates {state.body_rates.tolist()}')
            else:
                stamp_ns, *pose = self._pose_of(raw)
        except ValueError as exc:
            self._refuse_state(exc)
            return
        now_ns = now_ns_of(self.get_clock())
        if stamp_ns > now_ns + self._period_ns:
            self.node_counts['future_odom'] += 1
            self.last_future_odom = f'stamp {stamp_ns * 1e-9:.6f} s > clock {now_ns * 1e-9:.6f} s + one period'
            self.get_logger().warn(f'odom refused: {self.last_future_odom} (ahead of this node\'s clock); '
                                   f'{self.node_counts["future_odom"]} so far', throttle_duration_sec=1.0)
            return
        if pose is not None:
            try:
                state = self.pose_filter.update(stamp_ns, *pose)
            except PoseNotNewer:   # a repeated or reordered frame: the newer one stands
                self.node_counts['old_poses'] += 1
                return
            except ValueError as exc:
                self._refuse_state(exc)
                return
        if self.odom_fault is not None:
            self.get_logger().info('odom finite again: control resumes')
            self.odom_fault = None
        self.odom_received_ns = time.monotonic_ns()
        self._publish(self.loop.set_odometry(stamp_ns, state))

    def _refuse_state(self, exc: ValueError):
        """A non-finite state: counted, and a fault (no setpoints) until a finite one comes."""
        self.node_counts['nonfinite_odom'] += 1
        first = self.odom_fault is None
        self.odom_fault = f'odom refused (non-finite): {exc}'
        if first:
            self._fault(self.odom_fault)

    def _on_engaged(self, msg: Bool):
        """vehicle/engaged: the plan's clock runs only while the vehicle flies our setpoints (quad_control.loop)."""
        self._take_trajectories()   # a plan that arrived before the hand-over is re-based with it
        self._publish(self.loop.set_engaged(self.get_clock().now().nanoseconds, bool(msg.data)))
        self.publish_diagnostics()

    def _take_waiting_odometry(self) -> bool:
        """Odometry that arrived but was not yet taken (this process was not scheduled, or the executor ran the
        tick first): taken now, so staleness means none arrived, not none handled yet. True if any was."""
        taken = False
        while (msg := self.state_sub.handle.take_message(self.state_sub.msg_type, self.state_sub.raw)) is not None:
            self._on_odom(msg[0])
            taken = True
        return taken

    def _take_trajectories(self):
        """The decoder's results, on the executor's thread (guard condition, and every tick)."""
        for result in self.trajectory_decoder.take():
            if result[0] == 'refused':
                self.node_counts['rejected_trajectories'] += 1
                self._fault(f'trajectory refused, previous one kept: {result[1]}')
                continue
            _, start_ns, traj, decode_s = result
            self.get_logger().info(f'trajectory: {len(traj.times_s)} samples, {traj.duration_s:.2f} s, '
                                   f'starts at {start_ns * 1e-9:.3f} s (decoded in {1e3 * decode_s:.1f} ms)')
            self._publish(self.loop.set_trajectory(start_ns, traj, received_ns=self.get_clock().now().nanoseconds))

    def _on_change(self, changed: dict):
        values = self.params.values
        self.controller.gains = gains_from(values)
        self.controller.limits = Limits.of(self.vehicle, values['max_tilt_deg'])
        self.loop.max_start_step_m = values['max_start_step_m']
        self.loop.engage_delay_s = values['engage_delay_s']
        self.loop.wait_for_trajectory = values['wait_for_trajectory']
        if 'controller' in changed:
            try:   # a new controller from the next tick on; the loop's rules (hold point, plan) are kept
                self.controller = self.loop.controller = self._make_controller(values)
                self.loop.dead = None
            except ControllerRefused as exc:
                self._fault(f'{exc}; keeping {self.controller.name}')
        if 'rate_hz' in changed:
            self.loop.rate_hz = values['rate_hz']
            if hasattr(self.controller, 'period_s'):   # a user class must finish within the tick
                self.controller.period_s = 1.0 / values['rate_hz']
            self.destroy_timer(self.timer)
            self.timer = self.create_timer(1.0 / values['rate_hz'], self._on_tick)
            self.tick_times_ns.clear()
        if 'lockstep' in changed:
            self.loop.lockstep = values['lockstep']
            if hasattr(self.controller, 'wall_clock'):
                self.controller.wall_clock = not values['lockstep']
            self.loop.clear_pending()
        self.get_logger().info(f'parameters changed: {changed}')

    # --- the loop (rules: quad_control.loop) ----------------------------------------------------

    @property
    def _period_ns(self) -> int:
        return round(1e9 / self.loop.rate_hz)

    def _on_tick(self):
        self._take_trajectories()
        now_ns = now_ns_of(self.get_clock())
        if self.loop.lockstep:
            if self.loop.pending_tick_ns is None:
                self.pending_since_ns = time.monotonic_ns()
            if self.odom_fault is None:
                self._publish(self.loop.tick(now_ns))
            else:  # the tick waits for a finite odometry
                self.loop.pending_tick_ns = now_ns
            return
        if self.loop.odom is None or self.odom_fault is not None:
            return
        age_s = (time.monotonic_ns() - self.odom_received_ns) * 1e-9
        if age_s > self.params['odom_timeout_s'] and self._take_waiting_odometry():
            age_s = (time.monotonic_ns() - self.odom_received_ns) * 1e-9
        if age_s > self.params['odom_timeout_s']:
            if not self.stale:
                self.stale = True
                self.node_counts['odom_timeouts'] += 1
                self._fault(f'odom stale ({age_s:.3f} s > odom_timeout_s {self.params["odom_timeout_s"]}): '
                            'setpoints stopped')
            return
        self._publish(self.loop.tick(now_ns))

    def _publish(self, tick: Tick | None):
        if tick is None:
            return
        if self.stale:  # the hold point stays where it was anchored (quad_control.loop)
            self.stale = False
            self.get_logger().info('odom fresh again: control resumes')
            self.publish_diagnostics()
        if not self.context.ok():  # shutting down (SIGINT/SIGTERM): publishers are gone
            return
        self.cmd_pub.publish(self._setpoint_packer.pack(tick.setpoint, tick.t_ns))
        if self.ref_pub.get_subscription_count():   # packing it is ~60 us; a fleet's controllers publish it to nobody
            self.ref_pub.publish(self._reference_packer.pack(tick.reference, tick.t_ns))
        self.tick_times_ns.append(tick.t_ns)
        if self.loop.odom is not None:
            self.odom_age_ns[0] += tick.t_ns - self.loop.odom[0]
            self.odom_age_ns[1] += 1

    # --- reporting ------------------------------------------------------------------------------

    def _fault(self, reason: str):
        self.last_error = reason
        self.get_logger().error(reason)
        self.publish_diagnostics(fault=reason)

    def _mean_odom_age_ms(self) -> str | None:
        """Mean tick - odometry stamp (ms) of the setpoints since the last call (None: none published)."""
        total_ns, count = self.odom_age_ns
        self.odom_age_ns = [0, 0]
        return f'{total_ns * 1e-6 / count:.3f}' if count else None

    def _loop_rate_hz(self, now_ns: int) -> float:
        window_ns = int(DIAGNOSTICS_PERIOD_S * 2e9)
        recent = [t for t in self.tick_times_ns if t >= now_ns - window_ns]
        return (len(recent) - 1) / ((recent[-1] - recent[0]) * 1e-9) if len(recent) > 1 and recent[-1] > recent[0] \
            else 0.0

    def publish_diagnostics(self, fault: str | None = None):
        """The periodic status; `fault` (a refused input) makes this one ERROR with that message. Before the first
        /clock (use_sim_time) it is stamped 0, ROS's "no time yet", so a start-up can be followed."""
        now_ns = self.get_clock().now().nanoseconds
        timeout_s = self.params['odom_timeout_s']
        deferred_s = (time.monotonic_ns() - self.pending_since_ns) * 1e-9
        level, message = diagnostics.OK, self.loop.mode(now_ns)
        if fault is not None:
            level, message = diagnostics.ERROR, fault
        elif self.loop.dead is not None:   # a user controller failed: no setpoints (quad_control.loop)
            level, message = diagnostics.ERROR, self.loop.dead
        elif self.odom_fault is not None:
            level, message = diagnostics.ERROR, self.odom_fault
        elif self.stale:
            level, message = diagnostics.ERROR, f'odom stale (> {timeout_s} s): no setpoints'
        elif self.loop.lockstep and self.loop.pending_tick_ns is not None and deferred_s > timeout_s:
            level, message = diagnostics.ERROR, f'lockstep: no odom stamped >= tick for {deferred_s:.2f} s'
        elif self.loop.odom is None:
            level, message = diagnostics.WARN, 'waiting for odom'
        values = {'controller': self.controller.name, 'mode': self.loop.mode(now_ns), 'engaged': self.loop.engaged,
                  'lockstep': self.params['lockstep'], 'rate_hz': self.params['rate_hz'],
                  'loop_rate_hz': f'{self._loop_rate_hz(now_ns):.2f}', **self.counts,
                  'integral_m_s': np.round(self.controller.integral_m_s, 4).tolist(), 'last_error': self.last_error,
                  'drag_learnt_per_s': self._drag_learnt_per_s(),
                  'hold_position_m': None if self.loop.hold is None else self.loop.hold.position.tolist(),
                  'start_step_m': self.loop.last_start_step_m, 'max_start_step_m': self.loop.max_start_step_m,
                  'last_future_odom': self.last_future_odom, 'realtime': self.realtime,
                  contract.CONTROLLER_ODOM_AGE_MS: self._mean_odom_age_ms()}
        if level == diagnostics.OK and self.realtime_refused:
            level, message = diagnostics.WARN, f'realtime {self.realtime}'
        self.diag_pub.publish(diagnostics.array(_stamp(now_ns), [
            diagnostics.status(contract.CONTROLLER_STATUS, level, message, values)]))

    def _drag_learnt_per_s(self):
        """The drag learnt in flight (quad_control.drag_estimate); None while not learning (or a user class)."""
        estimate = getattr(self.controller, 'drag', None)
        return None if estimate is None else round(float(estimate.drag_per_s), 3)


def main(args=None):
    run_node(NODE_NAME, PositionControllerNode, refused=(ValueError, OSError),
             make_executor=lambda node: HotPathExecutor(node.hot_entities), args=args)


if __name__ == '__main__':
    main()
