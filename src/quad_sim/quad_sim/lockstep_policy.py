"""The simulator's lockstep policy, free of ROS (sim_node wires it to the graph; docs/quad_sim.md).

Lockstep: at sim time t_k publish odom (stamp t_k), then /clock (t_k); wait for a cmd/attitude_thrust stamped
>= t_k or lockstep_timeout_s of wall time; advance one period holding that setpoint.
- Setpoints (`classify_setpoint`): one stamped before the one applied is ignored; one stamped more than
  FUTURE_LIMIT_PERIODS ahead of sim time is refused (counted): taken as "the newest", it would make every later,
  correctly stamped one look old.
- Deadlines (`setpoint_timeout_s`): after a missed lockstep_timeout_s the controller is lost
  (`VehicleLockstep.missed_deadline`) and each step waits LOST_STEP_TIMEOUT_S at most until a setpoint arrives
  again, and not at all while no setpoint publisher is left (a dead controller: the failsafe lands the vehicle in
  seconds, not one step per timeout; a controller that was only slow catches up).
- Start-up: until the first setpoint, step k is re-published every STARTUP_REPUBLISH_S (`SetpointWait`,
  `FollowerWait`: for nodes that join late), and the step advances only when a controller is on the graph
  (`may_advance`): start-up order does not matter, and a controller whose first tick is after t = 0 still starts
  the run.
- Followers (`Followers`, `FollowerWait`): each step also waits, without a timeout, until every follower has
  acknowledged odometry within a lag of it (a recorder that falls behind slows the run instead of losing samples;
  a warning every FOLLOWER_WARN_S names the ones behind); at a stop (`DrainWatch`) the wait for the last step goes
  on while their acknowledgements advance, and ends when none did for DRAIN_STALL_S.
- Realtime (`RealtimePacer`): sim time runs to rtf x elapsed wall time, in whole physics steps.
- `RunClock`: the real-time factor, and where a run lost its wall time (its longest waits).

Times are integers in ns for sim time and floats in s for wall time; the wall clock is passed in (`now_s`), so
the policy is tested with a fake clock.
"""

STARTUP_REPUBLISH_S = 0.1   # wall time between re-publications of the first step until a setpoint arrives
LOST_STEP_TIMEOUT_S = 0.02  # wall time per step for a setpoint once one missed lockstep_timeout_s
FUTURE_LIMIT_PERIODS = 1    # a setpoint stamped more than this many periods ahead of sim time is refused
DRAIN_STALL_S = 30.0        # wall time, at shutdown, a follower may go without acknowledging anything new
FOLLOWER_WARN_S = 5.0       # wall time waiting for a follower before each warning naming it

TAKE, OLDER, FUTURE = 'take', 'older', 'future'


def classify_setpoint(stamp_ns: int, applied_stamp_ns: int, sim_time_ns: int, period_ns: int) -> str:
    """OLDER: stamped before the one applied (ignored); FUTURE: stamped after sim_time + FUTURE_LIMIT_PERIODS
    periods (refused: taken as the newest, it would make every later, correctly stamped one look old); else
    TAKE."""
    if stamp_ns < applied_stamp_ns:
        return OLDER
    if stamp_ns > sim_time_ns + FUTURE_LIMIT_PERIODS * period_ns:
        return FUTURE
    return TAKE


def setpoint_timeout_s(lockstep_timeout_s: float, setpoints_received: int, controller_lost: bool,
                       has_setpoint_publisher: bool) -> float:
    """Wall time one step waits for a vehicle's setpoint: lockstep_timeout_s; before its first setpoint
    STARTUP_REPUBLISH_S at most; once one was missed LOST_STEP_TIMEOUT_S at most (a controller that is only slow
    catches up), and none at all once no setpoint publisher is left (a dead controller's vehicle lands by its
    failsafe at full speed)."""
    timeout_s = lockstep_timeout_s if setpoints_received else min(lockstep_timeout_s, STARTUP_REPUBLISH_S)
    if controller_lost:
        timeout_s = min(timeout_s, LOST_STEP_TIMEOUT_S if has_setpoint_publisher else 0.0)
    return timeout_s


def may_advance(vehicles, t_k_ns: int) -> bool:
    """The step advances once every vehicle, a (setpoint_stamp_ns, setpoints_received, controller_present)
    triple with controller_present a callable (a graph query, asked only when needed), has a setpoint for t_k,
    has had one, or has a controller on the graph (a controller whose first tick is after t = 0 still starts the
    run; before one is there, time holds)."""
    return all(stamp_ns >= t_k_ns or received > 0 or controller_present()
               for stamp_ns, received, controller_present in vehicles)


class VehicleLockstep:
    """One vehicle's lockstep bookkeeping: the newest setpoint applied (its stamp; how many so far), the
    future-stamped ones refused, whether its controller is lost, and the distinct odometry steps published (a bag
    is checked against that count)."""

    def __init__(self):
        self.setpoint_stamp_ns = -1
        self.setpoints_received = 0
        self.future_setpoints = 0
        self.controller_lost = False   # a setpoint missed lockstep_timeout_s: LOST_STEP_TIMEOUT_S per step at most
        self.steps_published = 0
        self.last_odom_ns = -1

    def classify(self, stamp_ns: int, sim_time_ns: int, period_ns: int) -> str:
        """classify_setpoint against the setpoint applied; a FUTURE one is counted."""
        verdict = classify_setpoint(stamp_ns, self.setpoint_stamp_ns, sim_time_ns, period_ns)
        if verdict == FUTURE:
            self.future_setpoints += 1
        return verdict

    def applied(self, stamp_ns: int) -> bool:
        """A setpoint stamped stamp_ns was applied: the controller is back; True for the vehicle's first."""
        self.setpoint_stamp_ns = stamp_ns
        self.setpoints_received += 1
        self.controller_lost = False
        return self.setpoints_received == 1

    def missed_deadline(self) -> bool:
        """A step's wait ran out: a vehicle that had setpoints has lost its controller; True only when that is new
        (one warning per loss). Before the first setpoint a wait running out is start-up, not a loss."""
        if self.setpoints_received > 0 and not self.controller_lost:
            self.controller_lost = True
            return True
        return False

    def timeout_s(self, lockstep_timeout_s: float, has_setpoint_publisher) -> float:
        """setpoint_timeout_s for this vehicle; has_setpoint_publisher: a callable (a graph query), asked only
        once the controller is lost."""
        return setpoint_timeout_s(lockstep_timeout_s, self.setpoints_received, self.controller_lost,
                                  self.controller_lost and has_setpoint_publisher())

    def odometry_published(self, time_ns: int) -> None:
        """Counts distinct stamps: the first step re-published until a setpoint comes is one step."""
        if time_ns != self.last_odom_ns:
            self.steps_published += 1
        self.last_odom_ns = time_ns


class SetpointWait:
    """One step's wait for setpoints stamped >= t_k. `deadlines_s` maps each vehicle to its wall deadline
    (now_s + setpoint_timeout_s); `expire(now_s)` removes and returns the vehicles whose deadline passed;
    `republish_due(now_s)` says (once per STARTUP_REPUBLISH_S) that the step is to be re-published for the
    vehicles still without a first setpoint; `wake_in_s(now_s)` is how long to spin before looking again."""

    def __init__(self, waiting, deadlines_s: dict, now_s: float):
        self.waiting = list(waiting)
        self.deadlines_s = dict(deadlines_s)
        self.republish_at_s = now_s + STARTUP_REPUBLISH_S

    def expire(self, now_s: float) -> list:
        expired = [v for v in self.waiting if now_s >= self.deadlines_s[v]]
        self.waiting = [v for v in self.waiting if v not in expired]
        return expired

    def republish_due(self, now_s: float) -> bool:
        if now_s >= self.republish_at_s:
            self.republish_at_s = now_s + STARTUP_REPUBLISH_S
            return True
        return False

    def answered(self, has_setpoint_for_step) -> None:
        """Drops the vehicles for which has_setpoint_for_step(vehicle) is true."""
        self.waiting = [v for v in self.waiting if not has_setpoint_for_step(v)]

    def wake_in_s(self, now_s: float) -> float:
        return max(min(min(self.deadlines_s[v] for v in self.waiting), self.republish_at_s) - now_s, 0.0)


class Followers:
    """The lockstep followers' acknowledgements: the newest odometry stamp each has taken (-1: none yet)."""

    def __init__(self, names):
        self.acked_ns = dict.fromkeys(names, -1)

    def ack(self, name: str, stamp_ns: int) -> None:
        """An acknowledgement; one older than the newest (reordered) changes nothing."""
        self.acked_ns[name] = max(self.acked_ns[name], stamp_ns)

    def behind(self, stamp_ns: int) -> list[str]:
        """Followers whose newest acknowledged odometry is older than `stamp_ns`."""
        return [f for f, acked in self.acked_ns.items() if acked < stamp_ns]

    @staticmethod
    def step_target_ns(t_k_ns: int, lag_ns: int) -> int:
        """The stamp every follower must have acknowledged before step t_k goes on: t_k - lag, and step 0 before
        step 1 (every follower has the start)."""
        return max(t_k_ns - lag_ns, 0)


class FollowerWait:
    """One step's wait for the followers (no timeout): `republish_due(now_s, started)` once per
    STARTUP_REPUBLISH_S while no setpoint has come (followers joining late need the step again); `warn_due(now_s)`
    once per FOLLOWER_WARN_S (a warning naming the ones behind)."""

    def __init__(self, now_s: float):
        self.warned_s = self.republished_s = now_s

    def republish_due(self, now_s: float, started: bool) -> bool:
        if not started and now_s - self.republished_s >= STARTUP_REPUBLISH_S:
            self.republished_s = now_s
            return True
        return False

    def warn_due(self, now_s: float) -> bool:
        if now_s - self.warned_s > FOLLOWER_WARN_S:
            self.warned_s = now_s
            return True
        return False


class DrainWatch:
    """At a stop, the wait for the followers to take the last step: it goes on while their acknowledgements
    advance, however slowly; `stalled(acked_ns, now_s)` once none advanced for DRAIN_STALL_S."""

    def __init__(self, acked_ns: dict, now_s: float):
        self.acked_ns, self.progress_s = dict(acked_ns), now_s

    def stalled(self, acked_ns: dict, now_s: float) -> bool:
        if acked_ns != self.acked_ns:
            self.acked_ns, self.progress_s = dict(acked_ns), now_s
        return now_s - self.progress_s > DRAIN_STALL_S


class RealtimePacer:
    """Realtime mode: the sim time target runs at rtf x wall time (rtf may change between ticks);
    `steps_due(now_s, rtf, sim_time_ns, step_ns)` is the whole physics steps to reach it (0 while ahead)."""

    def __init__(self, now_s: float, sim_time_ns: int):
        self.last_wall_s, self.target_ns = now_s, float(sim_time_ns)

    def steps_due(self, now_s: float, rtf: float, sim_time_ns: int, step_ns: int) -> int:
        self.target_ns += (now_s - self.last_wall_s) * rtf * 1e9
        self.last_wall_s = now_s
        return max(int((self.target_ns - sim_time_ns) // step_ns), 0)


class RunClock:
    """Sim time against wall time since a (re)start (`real_time_factor`), and from the first step advanced on
    (`stepping`) the run's summary and its longest wall-time wait of each kind (where a slow run lost its time)."""

    def __init__(self, wall_s: float, sim_ns: int):
        self.wall_start_s, self.sim_start_ns = wall_s, sim_ns
        self.first_advance = None   # (wall s, sim ns, process CPU s) at the first step advanced
        self.longest = {}           # kind ('followers', 'setpoints') -> (wait s, at t ns, [who it waited for])

    def real_time_factor(self, wall_s: float, sim_ns: int) -> float:
        elapsed_s = wall_s - self.wall_start_s
        return (sim_ns - self.sim_start_ns) * 1e-9 / elapsed_s if elapsed_s > 0 else 0.0

    def advancing(self, wall_s: float, sim_ns: int, cpu_s: float) -> None:
        if self.first_advance is None:
            self.first_advance = (wall_s, sim_ns, cpu_s)

    @property
    def stepping(self) -> bool:
        return self.first_advance is not None

    def waited(self, what: str, wait_s: float, t_ns: int, who) -> None:
        """Keeps the longest wait of each kind while stepping (waits before the first step are start-up)."""
        if self.stepping and wait_s > self.longest.get(what, (0.0,))[0]:
            self.longest[what] = (wait_s, t_ns, list(who))

    def summary(self, wall_s: float, sim_ns: int, cpu_s: float) -> tuple[float, float, float]:
        """(sim s, wall s, CPU s) since the first step advanced."""
        wall0_s, sim0_ns, cpu0_s = self.first_advance
        return (sim_ns - sim0_ns) * 1e-9, wall_s - wall0_s, cpu_s - cpu0_s
