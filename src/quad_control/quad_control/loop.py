"""ControlLoop: the rules between a PositionController and its inputs (no rclpy), the one loop that
position_controller_node and the offline flight loop (quad_bringup.offline.closed_loop) both run.

- Engagement (docs/bridge.md): a plan's clock runs only while the vehicle flies our setpoints (`engaged`: the
  bridge's hand-over is active; a simulator is engaged at once). While not engaged the reference follows the
  vehicle (its position and yaw, every tick): the setpoints that stream before a hand-over hover where it is.
  At engagement at t_e the hold point is anchored where the vehicle is and the controller is reset; a plan
  whose start has passed begins at t_e + its own start delay (its stamp minus its arrival time, at least
  engage_delay_s: the vehicle settles under our setpoints first), a plan paused by the end of a hand-over
  resumes there from where it stopped; a plan still in the future keeps its stamp. A plan whose start was
  before t_e but which arrives after it, while the vehicle holds (none flown yet), starts as if it had come before
  the engagement (at t_e + engage_delay_s, or at its arrival if that is later).
  The end of a hand-over stops the plan's clock (the plan is paused, the reference follows the vehicle again).
- Hold before the plan: until a trajectory has started the reference is the hold point, anchored once at the
  first engaged odometry controlled from (its position and yaw) and never re-anchored while engaged (a
  stale-odometry event or a refused plan does not move it).
- A plan (start_ns, SampledTrajectory) is taken at its first tick t >= start_ns: reference(tau0 + t - start_ns)
  (tau0 = 0 for a new plan, the plan time it stopped at for a resumed one), after its end the final point.
  Taking it resets the controller (pid integral, disturbance observer).
- Start step: a plan whose reference at that first tick is farther than max_start_step_m from the vehicle is
  refused (the loop keeps what it tracked before; a fault names the distance), never flown as a step.
- dt = clamp(t - t_previous, 0, 2 / rate_hz), 0 at the first tick.
- A dead controller: a user controller that failed (quad_control.plugins.ControllerFailed: it raised, returned a
  bad or non-finite result, or took longer than the tick) is never called again and no tick produces a setpoint
  (one fault naming it): the vehicle is handled as with a dead controller process (the simulator's and the
  bridge's setpoint-timeout failsafes).
- Lockstep: the tick at t runs with the odometry stamped >= t, deferred until that arrives (a newer tick
  supersedes a pending one), and until the vehicle is engaged (the simulator engages at once, so a lockstep run
  never depends on when that message arrives); wait_for_trajectory also defers it until a plan is here.
"""

import math
from dataclasses import dataclass, replace

from quad_common import rotations
from quad_common.types import AttitudeSetpoint, Reference, State
from quad_control.plugins import ControllerFailed
from quad_control.position import PositionController, Saturation
from quad_control.velocity_blend import VelocityBlend

RATE_HZ = 100.0            # position_controller rate_hz and the offline loop's default
ENGAGE_DELAY_S = 1.0       # position_controller engage_delay_s
MAX_START_STEP_M = 0.5     # position_controller max_start_step_m and the offline loop's default
CONTROLLER_FAILED = 'controller failed'   # how the fault of a dead controller begins (fly's monitor ends on it)
# (Saturation's field, its count)
SATURATION_COUNTS = tuple((name, f'saturation_{name}') for name in ('thrust', 'tilt', 'integral'))
COUNTS = ('setpoints', 'deferred_ticks', 'superseded_ticks', 'control_errors', 'controller_failures',
          'refused_start_steps', *(count for _, count in SATURATION_COUNTS))


@dataclass(frozen=True)
class Plan:
    """A plan on the loop's clock: at node time t >= start_ns the reference is trajectory(tau0_s + t - start_ns).
    lead_ns: the plan's own start delay (its stamp minus its arrival), kept when it is re-based at engagement."""
    start_ns: int
    trajectory: object
    tau0_s: float = 0.0
    lead_ns: int = 0

    def time_s(self, t_ns: int) -> float:
        return self.tau0_s + (t_ns - self.start_ns) * 1e-9

    def reference(self, t_ns: int) -> Reference:
        return self.trajectory.reference(self.time_s(t_ns))


@dataclass
class Tick:
    """What one tick at t_ns produced (the node publishes it; the offline loop applies it)."""
    t_ns: int
    setpoint: AttitudeSetpoint
    reference: Reference
    saturation: Saturation


class ControlLoop:
    def __init__(self, controller: PositionController, rate_hz: float, *, lockstep: bool = False,
                 wait_for_trajectory: bool = False, max_start_step_m: float = math.inf, engaged: bool = True,
                 engage_delay_s: float = ENGAGE_DELAY_S, on_fault=None, on_event=None):
        """on_fault(reason): called with a one-line reason when a tick produces no setpoint or a plan is refused;
        on_event(line): an engagement, a pause or a re-based plan (informational). The odometry's velocity is
        blended with its position's derivative as the controller's gains.velocity_from_position_s say at the
        time (quad_control.velocity_blend)."""
        self.controller = controller
        self.rate_hz = float(rate_hz)
        self.lockstep = lockstep
        self.wait_for_trajectory = wait_for_trajectory
        self.max_start_step_m = float(max_start_step_m)
        self.on_fault = on_fault or (lambda reason: None)
        self.on_event = on_event or (lambda line: None)
        self.engaged = engaged       # the vehicle flies our setpoints (module docstring)
        self.engage_delay_s = float(engage_delay_s)
        self.engaged_ns = None       # when the vehicle last engaged (None: engaged from the start, or not engaged)
        self.odom = None             # (stamp_ns, State) of the newest accepted odometry
        self.trajectory = None       # Plan being tracked (or ended)
        self.next_plan = None        # Plan received (or paused), not started yet
        self.hold = None             # Reference: the hold point, anchored once
        self.pending_tick_ns = None  # lockstep: the tick waiting for its odometry
        self.last_control_ns = None
        self.last_start_step_m = None  # distance vehicle -> plan at the last plan start (taken or refused)
        self.dead = None             # why the controller failed (module docstring); None while it lives
        self.counts = dict.fromkeys(COUNTS, 0)
        self.velocity_blend = VelocityBlend()

    # --- inputs -------------------------------------------------------------------------------------

    def set_odometry(self, stamp_ns: int, state: State) -> Tick | None:
        """A finite odometry; in lockstep it may run the pending tick (returned)."""
        tau_s = getattr(getattr(self.controller, 'gains', None), 'velocity_from_position_s', 0.0)
        self.odom = (stamp_ns, self.velocity_blend(stamp_ns, state, tau_s))
        return self.run_pending()

    def set_trajectory(self, start_ns: int, trajectory, received_ns: int | None = None) -> Tick | None:
        """A new plan, started at its first engaged tick at or after start_ns (see the module docstring);
        received_ns: its arrival on the loop's clock (its start delay is start_ns - received_ns)."""
        lead_ns = 0 if received_ns is None else max(start_ns - received_ns, 0)
        plan = Plan(start_ns, trajectory, lead_ns=lead_ns)
        if (self.engaged and self.trajectory is None and self.engaged_ns is not None and start_ns < self.engaged_ns
                and received_ns is not None):
            # its start had passed at the engagement, which came first (a realtime simulator engages at its first
            # setpoint, maybe before the latched plan is here): it begins as it would have at the engagement
            plan = replace(plan, start_ns=max(self.engaged_ns + round(self.engage_delay_s * 1e9), received_ns))
            self.on_event(f'plan arrived at t = {received_ns * 1e-9:.3f} s, after its start '
                          f'{start_ns * 1e-9:.3f} s: it starts at t = {plan.start_ns * 1e-9:.3f} s')
        self.next_plan = plan
        return self.run_pending()

    def set_engaged(self, t_ns: int, engaged: bool) -> Tick | None:
        """The vehicle started (True) or stopped (False) flying our setpoints at t_ns (module docstring)."""
        if engaged == self.engaged:
            return None
        self.engaged = engaged
        self.engaged_ns = t_ns if engaged else None
        if not engaged:
            self.hold = None
            plan = self.trajectory
            if plan is not None and plan.time_s(t_ns) < plan.trajectory.duration_s and self.next_plan is None:
                tau_s = max(plan.time_s(t_ns), 0.0)
                self.next_plan = replace(plan, tau0_s=tau_s)
                self.on_event(f'hand-over ended at t = {t_ns * 1e-9:.3f} s: plan paused at {tau_s:.3f} s of '
                              f'{plan.trajectory.duration_s:.3f} s, following the vehicle')
            else:
                self.on_event(f'hand-over ended at t = {t_ns * 1e-9:.3f} s: following the vehicle')
            self.trajectory = None
            return None
        self.hold = None if self.odom is None else self._here(self.odom[1])   # where the vehicle is now
        self._reset_controller(t_ns)
        plan, line = self.next_plan, 'holding where the vehicle is'
        if plan is not None and (plan.tau0_s > 0.0 or plan.start_ns < t_ns):
            start_ns = t_ns + max(plan.lead_ns, round(self.engage_delay_s * 1e9))
            self.next_plan = replace(plan, start_ns=start_ns)
            what = f'resumes at {plan.tau0_s:.3f} s' if plan.tau0_s > 0.0 else 'starts'
            line += f'; the plan {what} at t = {start_ns * 1e-9:.3f} s'
        self.on_event(f'engaged at t = {t_ns * 1e-9:.3f} s: {line}')
        return self.run_pending()

    def clear_pending(self):
        self.pending_tick_ns = None

    # --- ticks --------------------------------------------------------------------------------------

    def tick(self, t_ns: int) -> Tick | None:
        """The timer tick at t_ns: lockstep defers it until its odometry; otherwise controls at once from the
        newest odometry (the node decides whether that odometry is fresh enough)."""
        if not self.lockstep:
            return None if self.odom is None else self.control(t_ns, self.odom[1])
        if self.pending_tick_ns is not None:
            self.counts['superseded_ticks'] += 1
        self.pending_tick_ns = t_ns
        out = self.run_pending()
        if self.pending_tick_ns is not None:
            self.counts['deferred_ticks'] += 1
        return out

    def run_pending(self) -> Tick | None:
        """Lockstep: the pending tick at t runs as soon as the odometry stamped >= t is here."""
        if self.pending_tick_ns is None or self.odom is None:
            return None
        if not self.engaged:   # the simulator engages at once: a lockstep run never depends on when that arrives
            return None
        if self.wait_for_trajectory and self.trajectory is None and self.next_plan is None:
            return None
        if self.odom[0] < self.pending_tick_ns:
            return None
        t_ns, self.pending_tick_ns = self.pending_tick_ns, None
        return self.control(t_ns, self.odom[1])

    def control(self, t_ns: int, state: State) -> Tick | None:
        """One controller step at t_ns from `state`; None (and on_fault) if the controller refuses or is dead."""
        if self.dead is not None:
            return None
        ref = self.reference(t_ns, state)
        period_s = 1.0 / self.rate_hz
        dt_s = 0.0 if self.last_control_ns is None else min(max((t_ns - self.last_control_ns) * 1e-9, 0.0),
                                                            2 * period_s)
        try:
            setpoint, sat = self.controller.update(state, ref, dt_s)
        except ControllerFailed as exc:
            self._die(t_ns, exc)
            return None
        except ValueError as exc:
            self.counts['control_errors'] += 1
            self.on_fault(f'no setpoint at t = {t_ns * 1e-9:.3f} s: {exc}')
            return None
        self.last_control_ns = t_ns
        self.counts['setpoints'] += 1
        for name, count in SATURATION_COUNTS:
            self.counts[count] += int(getattr(sat, name))
        return Tick(t_ns, setpoint, ref, sat)

    def _reset_controller(self, t_ns: int):
        try:
            self.controller.reset()
        except ControllerFailed as exc:
            self._die(t_ns, exc)

    def _die(self, t_ns: int, exc: ControllerFailed):
        self.counts['controller_failures'] += 1
        self.dead = f'{CONTROLLER_FAILED} at t = {t_ns * 1e-9:.3f} s, no setpoints from now on: {exc}'
        self.on_fault(self.dead)

    @staticmethod
    def _here(state: State) -> Reference:
        return Reference(position=state.position.copy(), yaw=float(rotations.to_euler(state.quaternion)[2]))

    def reference(self, t_ns: int, state: State) -> Reference:
        if not self.engaged:   # before a hand-over: hover where the vehicle is
            return self._here(state)
        if self.hold is None:
            self.hold = self._here(state)
        if self.next_plan is not None and t_ns >= self.next_plan.start_ns:
            self._start_plan(t_ns, state)
        if self.trajectory is None or t_ns < self.trajectory.start_ns:
            return self.hold
        return self.trajectory.reference(t_ns)  # after the end: the final point

    def _start_plan(self, t_ns: int, state: State):
        plan, self.next_plan = self.next_plan, None
        step_m = float(math.dist(plan.reference(t_ns).position, state.position))
        self.last_start_step_m = step_m
        if step_m > self.max_start_step_m:
            self.counts['refused_start_steps'] += 1
            self.on_fault(f'trajectory refused at its start (t = {t_ns * 1e-9:.3f} s): it begins {step_m:.3f} m '
                          f'from the vehicle > max_start_step_m {self.max_start_step_m} m; '
                          f'{"holding" if self.trajectory is None else "keeping the previous plan"}')
            return
        self.trajectory = plan
        self._reset_controller(t_ns)

    # --- status -------------------------------------------------------------------------------------

    def mode(self, t_ns: int) -> str:
        if self.dead is not None:
            return 'controller dead (no setpoints)'
        if not self.engaged:
            return 'not engaged (following the vehicle)' + (', plan waiting' if self.next_plan is not None else '')
        if self.trajectory is None:
            return 'hold (trajectory not started)' if self.next_plan is not None else 'hold (no trajectory)'
        plan = self.trajectory
        return 'tracking' if plan.time_s(t_ns) <= plan.trajectory.duration_s else 'hold (trajectory ended)'
