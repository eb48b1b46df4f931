"""position_controller: the fixed-rate position loop (pd | pid | se3) between `odom` and `cmd/attitude_thrust`.

Each tick at node-clock time t samples the latched `trajectory`, runs the controller on the newest
odometry and publishes `cmd/attitude_thrust` and `control/reference`, both stamped t.
lockstep: the tick waits for the odometry stamped >= t (contract: docs/quad_control.md).
Failsafe: stale or non-finite odometry -> no setpoint at all, ERROR on `diagnostics`.
"""

from collections import deque

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu
from trajectory_msgs.msg import MultiDOFJointTrajectory

from quad_common import cdr, conversions, diagnostics, lockstep, rotations
from quad_common.hot_path import HotPathExecutor
from quad_common.node_main import run_node
from quad_common.params import Param, ParameterSet
from quad_common.paths import resolve_config
from quad_common.types import Reference
from quad_common.vehicle import load_vehicle
from quad_control.position import CONTROLLERS, Limits, PositionController, PositionGains, gains_from_parameters

NODE_NAME = 'position_controller'
AXES = ('x', 'y', 'z')
SEED = PositionGains()
DIAGNOSTICS_PERIOD_S = 1.0

SPECS = [
    Param('controller', 'pd', 'position controller: pd (the seed eq. 1-5), pid (plus integral), se3 (geometric)',
          choices=CONTROLLERS),
    Param('rate_hz', 100.0, 'control loop rate on the node clock; in lockstep 1 / sim lockstep_period_s',
          min=1.0, max=2000.0),
    Param('lockstep', False, 'compute the tick at t from the odometry stamped t (deferred until it arrives)'),
    Param('wait_for_trajectory', False, 'lockstep: defer the ticks (so simulated time waits) until a trajectory '
          'arrives; a late latched plan then never starts in the past'),
    Param('odom_timeout_s', 0.2, 'odometry older than this stops the setpoints (failsafe) and reports ERROR',
          min=0.001, max=10.0),
    Param('vehicle', 'config/vehicles/crazyflie.yaml', 'vehicle file: mass, thrust range, max tilt',
          read_only=True),
    Param('max_tilt_deg', 0.0, 'tilt limit of the command; 0 = the vehicle file max_tilt_deg', min=0.0, max=89.0),
    *[Param(f'kp_{a}', float(SEED.kp[i]), f'eq. 1 position gain, {a} axis (1/s^2)', min=0.0, max=1000.0)
      for i, a in enumerate(AXES)],
    *[Param(f'kd_{a}', float(SEED.kd[i]), f'eq. 1 velocity gain, {a} axis (1/s)', min=0.0, max=1000.0)
      for i, a in enumerate(AXES)],
    *[Param(f'ki_{a}', float(SEED.ki[i]), f'pid integral gain, {a} axis (1/s^3)', min=0.0, max=1000.0)
      for i, a in enumerate(AXES)],
    Param('integral_limit_mps2', SEED.integral_limit_mps2, 'anti-windup clamp on ki * integral, per axis (m/s^2)',
          min=0.0, max=100.0),
    Param('use_feedforward', True, 'reference acceleration in eq. 1 and jerk-based body rates in se3'),
    Param('attitude_lead_s', SEED.attitude_lead_s, 'attitude from a_des + lead * reference jerk, cancelling the '
          'onboard attitude loop lag (about kd/kp of eq. 6 = 0.1 s); 0 = off (the seed)', min=0.0, max=1.0),
    Param('thrust_scale', SEED.thrust_scale, 'delivered / commanded specific force of the vehicle (quadflight '
          'identify); the thrust command is divided by it; 1 = the seed', min=0.5, max=2.0),
    Param('disturbance_time_constant_s', SEED.disturbance_time_constant_s, 'filter time constant of the observed '
          'external acceleration (drag, wind) subtracted from a_des; 0 = off (the seed)', min=0.0, max=10.0),
]


gains_from = gains_from_parameters


def _stamp_ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def _stamp(t_ns: int):
    return rclpy.time.Time(nanoseconds=t_ns).to_msg()


class PositionControllerNode(Node):
    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        self.params = ParameterSet(self, SPECS, on_change=self._on_change)
        self.vehicle = load_vehicle(resolve_config(self.params['vehicle']))
        self.controller = PositionController(self.params['controller'], gains_from(self.params.values), self.vehicle,
                                             Limits.of(self.vehicle, self.params['max_tilt_deg']))
        self.odom = None            # (stamp_ns, received_steady_ns, State) of the newest finite odometry
        self.odom_fault = None      # reason the newest odometry was refused (non-finite), until a good one
        self.trajectory = None      # (start_ns, SampledTrajectory)
        self.hold = None            # Reference held before any trajectory
        self.pending_tick_ns = None  # lockstep: tick waiting for its odometry
        self.pending_since_ns = 0
        self.last_control_ns = None
        self.stale = False
        self.last_error = ''
        self.tick_times_ns = deque(maxlen=4096)
        self.counts = dict.fromkeys(('setpoints', 'deferred_ticks', 'superseded_ticks', 'odom_timeouts',
                                     'nonfinite_odom', 'rejected_trajectories', 'control_errors',
                                     'saturation_thrust', 'saturation_tilt', 'saturation_integral'), 0)
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        # lockstep: as deep as the simulator's paced topics, so its followers (the recorder) lose no setpoint
        paced = lockstep.PACED if self.params['lockstep'] else reliable
        self.cmd_pub = self.create_publisher(Imu, 'cmd/attitude_thrust', paced)
        self.ref_pub = self.create_publisher(MultiDOFJointTrajectory, 'control/reference', paced)
        self.diag_pub = self.create_publisher(DiagnosticArray, 'diagnostics', reliable)
        self.odom_sub = self.create_subscription(Odometry, 'odom', self._on_odom, reliable, raw=True)
        self._setpoint_packer = cdr.SetpointPacker()
        self._reference_packer = cdr.ReferencePacker()
        self.trajectory_sub = self.create_subscription(MultiDOFJointTrajectory, 'trajectory', self._on_trajectory,
                                                       latched)
        self.timer = self.create_timer(1.0 / self.params['rate_hz'], self._on_tick)
        self.steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(DIAGNOSTICS_PERIOD_S, self.publish_diagnostics, clock=self.steady)
        self.get_logger().info(f"{self.params['controller']} at {self.params['rate_hz']} Hz, "
                               f"lockstep={self.params['lockstep']}, vehicle {self.vehicle.name}")

    def hot_entities(self):
        """What a tick needs at once (HotPathExecutor): /clock (use_sim_time), odom, the tick timer, and the
        trajectory (rare, but a new plan must not wait for the executor's slow pass)."""
        clock = [s for s in self.subscriptions if s.topic_name == '/clock']
        return clock + [self.odom_sub, self.trajectory_sub], [self.timer]

    # --- inputs ---------------------------------------------------------------------------------

    def _on_odom(self, raw: bytes):
        """odom, serialized (quad_common.cdr: the tick's critical path)."""
        try:
            stamp_ns, state = cdr.odometry_to_state(raw)
            if not state.is_finite():
                raise ValueError(f'position {state.position.tolist()}, velocity {state.velocity.tolist()}, '
                                 f'body rates {state.body_rates.tolist()}')
        except ValueError as exc:
            self.counts['nonfinite_odom'] += 1
            first = self.odom_fault is None
            self.odom_fault = f'odom refused (non-finite): {exc}'
            if first:
                self._fault(self.odom_fault)
            return
        if self.odom_fault is not None:
            self.get_logger().info('odom finite again: control resumes')
            self.odom_fault = None
        self.odom = (stamp_ns, self.steady.now().nanoseconds, state)
        self._run_pending_tick()

    def _on_trajectory(self, msg: MultiDOFJointTrajectory):
        try:
            start_s, traj = conversions.msg_to_sampled(msg)
        except ValueError as exc:
            self.counts['rejected_trajectories'] += 1
            self._fault(f'trajectory refused, previous one kept: {exc}')
            return
        self.trajectory = (_stamp_ns(msg.header.stamp), traj)
        self.controller.reset()
        self.get_logger().info(f'trajectory: {len(traj.times_s)} samples, {traj.duration_s:.2f} s, '
                               f'starts at {start_s:.3f} s')
        self._run_pending_tick()

    def _on_change(self, changed: dict):
        values = self.params.values
        self.controller.gains = gains_from(values)
        self.controller.limits = Limits.of(self.vehicle, values['max_tilt_deg'])
        if 'controller' in changed:
            self.controller.name = values['controller']
            self.controller.reset()
        if 'rate_hz' in changed:
            self.destroy_timer(self.timer)
            self.timer = self.create_timer(1.0 / values['rate_hz'], self._on_tick)
            self.tick_times_ns.clear()
        if 'lockstep' in changed:
            self.pending_tick_ns = None
        self.get_logger().info(f'parameters changed: {changed}')

    # --- the loop -------------------------------------------------------------------------------

    def _on_tick(self):
        now_ns = self.get_clock().now().nanoseconds
        if self.params['lockstep']:
            if self.pending_tick_ns is not None:
                self.counts['superseded_ticks'] += 1
            else:
                self.pending_since_ns = self.steady.now().nanoseconds
            self.pending_tick_ns = now_ns
            self._run_pending_tick()
            if self.pending_tick_ns is not None:
                self.counts['deferred_ticks'] += 1
            return
        if self.odom is None or self.odom_fault is not None:
            return
        age_s = (self.steady.now().nanoseconds - self.odom[1]) * 1e-9
        if age_s > self.params['odom_timeout_s']:
            if not self.stale:
                self.stale = True
                self.counts['odom_timeouts'] += 1
                self._fault(f'odom stale ({age_s:.3f} s > odom_timeout_s {self.params["odom_timeout_s"]}): '
                            'setpoints stopped')
            return
        self._control(now_ns, self.odom[2])

    def _run_pending_tick(self):
        """Lockstep: the pending tick at t runs as soon as the odometry stamped >= t is here."""
        if self.pending_tick_ns is None or self.odom is None or self.odom_fault is not None:
            return
        if self.trajectory is None and self.params['wait_for_trajectory']:
            return
        if self.odom[0] < self.pending_tick_ns:
            return
        t_ns, self.pending_tick_ns = self.pending_tick_ns, None
        self._control(t_ns, self.odom[2])

    def _reference(self, t_ns: int, state) -> Reference:
        if self.hold is None:
            self.hold = Reference(position=state.position.copy(), yaw=float(rotations.to_euler(state.quaternion)[2]))
        if self.trajectory is None or t_ns < self.trajectory[0]:
            return self.hold
        return self.trajectory[1].reference((t_ns - self.trajectory[0]) * 1e-9)  # after the end: the final point

    def _control(self, t_ns: int, state):
        if self.stale:
            self.stale = False
            if self.trajectory is None:
                self.hold = None  # the vehicle's failsafe may have moved it: hold where it is now
            self.get_logger().info('odom fresh again: control resumes')
            self.publish_diagnostics()
        ref = self._reference(t_ns, state)
        period_s = 1.0 / self.params['rate_hz']
        dt_s = 0.0 if self.last_control_ns is None else min(max((t_ns - self.last_control_ns) * 1e-9, 0.0),
                                                            2 * period_s)
        try:
            setpoint, sat = self.controller.update(state, ref, dt_s)
        except ValueError as exc:
            self.counts['control_errors'] += 1
            self._fault(f'no setpoint at t = {t_ns * 1e-9:.3f} s: {exc}')
            return
        self.last_control_ns = t_ns
        if not self.context.ok():  # shutting down (SIGINT/SIGTERM): publishers are gone
            return
        self.cmd_pub.publish(self._setpoint_packer.pack(setpoint, t_ns))
        self.ref_pub.publish(self._reference_packer.pack(ref, t_ns))
        self.counts['setpoints'] += 1
        for name in ('thrust', 'tilt', 'integral'):
            self.counts[f'saturation_{name}'] += int(getattr(sat, name))
        self.tick_times_ns.append(t_ns)

    # --- reporting ------------------------------------------------------------------------------

    def _fault(self, reason: str):
        self.last_error = reason
        self.get_logger().error(reason)
        self.publish_diagnostics(fault=reason)

    def _mode(self, now_ns: int) -> str:
        if self.trajectory is None:
            return 'hold (no trajectory)'
        start_ns, traj = self.trajectory
        if now_ns < start_ns:
            return 'hold (trajectory not started)'
        return 'tracking' if (now_ns - start_ns) * 1e-9 <= traj.duration_s else 'hold (trajectory ended)'

    def _loop_rate_hz(self, now_ns: int) -> float:
        window_ns = int(DIAGNOSTICS_PERIOD_S * 2e9)
        recent = [t for t in self.tick_times_ns if t >= now_ns - window_ns]
        return (len(recent) - 1) / ((recent[-1] - recent[0]) * 1e-9) if len(recent) > 1 and recent[-1] > recent[0] \
            else 0.0

    def publish_diagnostics(self, fault: str | None = None):
        """The periodic status; `fault` (a refused input) makes this one ERROR with that message."""
        now_ns = self.get_clock().now().nanoseconds
        timeout_s = self.params['odom_timeout_s']
        deferred_s = (self.steady.now().nanoseconds - self.pending_since_ns) * 1e-9
        level, message = diagnostics.OK, self._mode(now_ns)
        if fault is not None:
            level, message = diagnostics.ERROR, fault
        elif self.odom_fault is not None:
            level, message = diagnostics.ERROR, self.odom_fault
        elif self.stale:
            level, message = diagnostics.ERROR, f'odom stale (> {timeout_s} s): no setpoints'
        elif self.params['lockstep'] and self.pending_tick_ns is not None and deferred_s > timeout_s:
            level, message = diagnostics.ERROR, f'lockstep: no odom stamped >= tick for {deferred_s:.2f} s'
        elif self.odom is None:
            level, message = diagnostics.WARN, 'waiting for odom'
        values = {'controller': self.controller.name, 'mode': self._mode(now_ns),
                  'lockstep': self.params['lockstep'], 'rate_hz': self.params['rate_hz'],
                  'loop_rate_hz': f'{self._loop_rate_hz(now_ns):.2f}', **self.counts,
                  'integral_m_s': np.round(self.controller.integral_m_s, 4).tolist(), 'last_error': self.last_error}
        self.diag_pub.publish(diagnostics.array(_stamp(now_ns), [
            diagnostics.status(f'{NODE_NAME}: cmd/attitude_thrust', level, message, values)]))


def main(args=None):
    run_node(NODE_NAME, PositionControllerNode, refused=(ValueError, OSError),
             make_executor=lambda node: HotPathExecutor(node.hot_entities), args=args)


if __name__ == '__main__':
    main()
