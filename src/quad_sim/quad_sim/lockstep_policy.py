"""The simulator's lockstep policy, free of ROS: which setpoint a vehicle takes, how long a step waits for one,
when the first step is re-published and when the step may advance (sim_node wires it to the graph).

Times are integers in ns for sim time and floats in s for wall time; the wall clock is passed in (`now_s`), so
the policy is tested with a fake clock.
"""

STARTUP_REPUBLISH_S = 0.1   # wall time between re-publications of the first step until a setpoint arrives
LOST_STEP_TIMEOUT_S = 0.02  # wall time per step for a setpoint once one missed lockstep_timeout_s
FUTURE_LIMIT_PERIODS = 1    # a setpoint stamped more than this many periods ahead of sim time is refused

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
