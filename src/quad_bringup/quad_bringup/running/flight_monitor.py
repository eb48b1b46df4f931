"""In-process watcher of a flight (fly's eyes): trajectory, odometry and diagnostics -> a verdict.

The judgement itself (`FlightJudge`) has no rclpy: it is fed plain numbers, so it is unit-tested.
The monitor is a lockstep follower (quad_common.ros.lockstep, as MONITOR): the simulator never runs more than a few
steps ahead of what it has judged, so the verdict is computed from every odometry sample, as the report is.
"""

from dataclasses import dataclass

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry
from trajectory_msgs.msg import MultiDOFJointTrajectory

from quad_bringup.analysis.metrics import Completion
from quad_bringup.running.graph import MONITOR
from quad_common import contract, conversions
from quad_common.diagnostics import ERROR, level_of
from quad_common.ros import cdr, lockstep
from quad_common.ros.hot_path import HotPathExecutor
from quad_control.loop import CONTROLLER_FAILED


@dataclass
class Verdict:
    ok: bool
    reason: str


class FlightJudge:
    """Decides when a flight is over: completed, collided, diverged or out of time (simulated seconds)."""

    def __init__(self, rule: Completion, divergence_m=1.0, time_limit_factor=3.0, time_limit_margin_s=10.0,
                 hold_after_completion_s=0.5):
        self.rule = rule
        self.divergence_m = divergence_m
        self.time_limit_factor = time_limit_factor
        self.time_limit_margin_s = time_limit_margin_s
        self.hold_after_completion_s = hold_after_completion_s
        self.start_s = None
        self.trajectory = None
        self.t_s = None
        self.error_m = float('nan')
        self.completed_at_s = None
        self.verdict = None

    def set_trajectory(self, start_s, trajectory):
        self.start_s, self.trajectory = start_s, trajectory
        self.arrival_s = self.rule.plan_arrival_s(trajectory)

    @property
    def planned_s(self):
        return None if self.trajectory is None else self.trajectory.duration_s

    def on_collision(self, t_s, message):
        """t_s: the collision's own time (the contract's collision_time_s), message: the status's message."""
        if self.verdict is None:
            self.verdict = Verdict(False, f'collision at t = {self._since_start(t_s):.2f} s: {message}')

    def on_controller_failed(self, message):
        """A user controller died (quad_control.loop): the vehicle gets no setpoint from it again."""
        if self.verdict is None:
            self.verdict = Verdict(False, message)

    def on_odometry(self, t_s, position, velocity):
        self.t_s = t_s
        if self.trajectory is None or self.verdict is not None:
            return
        elapsed = t_s - self.start_s
        desired = self.trajectory.reference(elapsed).position   # one time: not evaluate's array set-up
        self.error_m = float(np.linalg.norm(position - desired))
        if not (np.all(np.isfinite(position)) and self.error_m <= self.divergence_m):
            self.verdict = Verdict(False, f'diverged at t = {elapsed:.2f} s: position error {self.error_m:.3f} m '
                                          f'> {self.divergence_m} m')
            return
        done = self.rule.done(elapsed, position, velocity, self.trajectory, self.arrival_s)
        if done and self.completed_at_s is None:
            self.completed_at_s = elapsed
        if self.completed_at_s is not None and elapsed >= self.completed_at_s + self.hold_after_completion_s:
            self.verdict = Verdict(True, f'completed at t = {self.completed_at_s:.2f} s '
                                         f'(planned {self.planned_s:.2f} s)')
        elif elapsed > self.time_limit_s:
            self.verdict = Verdict(False, f'time limit: not complete after {elapsed:.1f} s '
                                          f'(planned {self.planned_s:.1f} s; limit {self.time_limit_s:.1f} s)')

    @property
    def time_limit_s(self):
        return self.time_limit_factor * self.planned_s + self.time_limit_margin_s

    def _since_start(self, t_s):
        return t_s - self.start_s if self.start_s is not None else t_s

    def progress(self) -> str:
        if self.trajectory is None or self.t_s is None:
            return 'waiting for the trajectory and odometry'
        return (f't = {self.t_s - self.start_s:6.2f} / {self.planned_s:.2f} s   '
                f'error {100 * self.error_m:6.2f} cm')


class FlightMonitor:
    """An rclpy node in its own context feeding a FlightJudge."""

    def __init__(self, domain_id: int, judge: FlightJudge):
        self.judge = judge
        self.recorded = {}  # topic -> messages in the bag, from the recorder's status on diagnostics
        self.published = {}  # the simulator's newest `sim_node: published` values (steps, future_setpoints_refused)
        self.published_stamp_ns = -1   # its stamp (sim time): the bag is checked up to it
        self.sim_events = {}  # diagnostics name -> (level, message, values) of the simulator's newest statuses
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id,
                   signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
        self.node = rclpy.create_node(MONITOR, context=self.context)
        self.ack = lockstep.Acknowledger(self.node, MONITOR)
        c = contract
        self._hot = [self.node.create_subscription(MultiDOFJointTrajectory, c.TRAJECTORY, self._on_trajectory,
                                                   c.qos(c.TRAJECTORY), raw=True),
                     self.node.create_subscription(Odometry, c.ODOM, self._on_odom, lockstep.PACED, raw=True),
                     self.node.create_subscription(DiagnosticArray, c.DIAGNOSTICS, self._on_diagnostics,
                                                   lockstep.PACED)]
        self.executor = HotPathExecutor(lambda: (self._hot, ()), context=self.context)
        self.executor.add_node(self.node)

    def _on_trajectory(self, raw: bytes):
        # the controller's decoder: the plan's arrays straight from its bytes (its ~1,200 points as rclpy message
        # objects, then msg_to_sampled, cost ~0.2 s of fly's start)
        stamp_ns, trajectory = cdr.trajectory_to_sampled(raw)
        self.judge.set_trajectory(conversions.ns_to_s(stamp_ns), trajectory)

    def _on_odom(self, raw: bytes):
        stamp_ns, state = cdr.odometry_to_state(raw)
        self.judge.on_odometry(conversions.ns_to_s(stamp_ns), state.position, state.velocity)
        self.ack.taken(stamp_ns)

    def _on_diagnostics(self, msg):
        for st in msg.status:
            if st.name == contract.RECORDER_STATUS:
                self.recorded = {kv.key: int(kv.value) for kv in st.values}
            elif st.name.startswith(contract.SIM_STATUS.format('')):
                values = {kv.key: kv.value for kv in st.values}
                self.sim_events[st.name] = (level_of(st), st.message, values)
                if st.name == contract.SIM_PUBLISHED:
                    stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
                    if stamp_ns >= self.published_stamp_ns:   # the newest count (they may arrive out of order)
                        self.published = {k: int(v) for k, v in values.items()}
                        self.published_stamp_ns = stamp_ns
            if st.name == contract.CONTROLLER_STATUS and level_of(st) == ERROR[0] and \
                    st.message.startswith(CONTROLLER_FAILED):
                self.judge.on_controller_failed(st.message)
            if level_of(st) == ERROR[0]:  # an event is a key of an ERROR status, not its name or message
                t_s = contract.event_time_s({kv.key: kv.value for kv in st.values}, contract.COLLISION_TIME_S)
                if t_s is not None:
                    self.judge.on_collision(t_s, st.message)

    def missing_readers(self, node_name: str, topics) -> list[str]:
        """The topics on which the graph does not (yet) show a subscription of node `node_name`."""
        return [t for t in topics if not any(
            info.node_name == node_name for info in self.node.get_subscriptions_info_by_topic(
                self.node.resolve_topic_name(t)))]

    def spin_once(self, timeout_s=0.1):
        self.executor.spin_once(timeout_sec=timeout_s)
        self.ack.flush_if_due()

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
