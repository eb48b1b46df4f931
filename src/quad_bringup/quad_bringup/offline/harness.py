"""One closed loop for every flight without ROS (no rclpy): position_controller's own ControlLoop (its rules:
hold before the plan, the plan's start and its start-step guard, the dt clamp, a dead controller, lockstep
deferral) on a plant, seeing the vehicle through a telemetry model. The offline flight (closed_loop, fleet_loop),
the twin (replay), the margin check (stability) and the bench's emulated chains all fly through `fly`.

Each period T, at t_k = start + k T:

    record the truth; stop when done(t_k, truth) or fault(t_k, truth)
    telemetry.observe(t_k, plant)          the plant's state enters the telemetry
    seen = telemetry.seen(t_k)             the newest odometry delivered by t_k: (stamp_ns, State) or None
    lockstep:  loop.tick(t_k), then loop.set_odometry(seen)       (the tick waits for the odometry stamped t_k)
    otherwise: loop.set_odometry(seen) when it is new, then loop.tick(t_k)    (the node's timer)
    plant.command(setpoint, T); plant.advance(T)

A period without a setpoint: before any odometry the plant gets `idle` (level at its yaw, hover thrust: the
vehicle holds its attitude until our stream starts); in lockstep the flight ends (the graph's controller would
never answer); otherwise the plant keeps the last setpoint, as a vehicle does between stream messages.

The plant: anything with `state` (truth), `observed()` (what its telemetry reports), `command(setpoint, dt_s)`
and `advance(dt_s)` (raising quad_sim.simulator.SimulationStopped): SimulatorPlant, or
quad_vehicle_emu.plant.AutopilotPlant (the emulated autopilot's response and estimate in front of it).
The telemetry: Fresh (the lockstep graph), FixedAge (a twin's measured age), DelayLine (a vehicle's link), Mocap
(the controller on motion capture).
"""

import collections
import math
from dataclasses import dataclass, field

import numpy as np

from quad_common import rotations
from quad_common.types import GRAVITY_MPS2, AttitudeSetpoint, State
from quad_control.loop import ControlLoop
from quad_control.pose_state import PoseStateFilter
from quad_sim.mocap import MocapConfig, MotionCapture
from quad_sim.simulator import SimulationStopped, Simulator


class SimulatorPlant:
    """quad_sim's Simulator as the plant: the setpoint straight to its onboard loop, its odometry as telemetry."""

    def __init__(self, sim: Simulator):
        self.sim = sim

    @property
    def state(self) -> State:
        return self.sim.state

    def observed(self) -> State:
        return self.sim.odometry_state()

    def command(self, setpoint: AttitudeSetpoint):
        self.sim.set_setpoint(setpoint)

    def advance(self, dt_s: float):
        self.sim.advance_steps(self.sim.steps_in(dt_s))


class Fresh:
    """The lockstep graph: at each tick the plant's odometry of that tick, stamped with it; latency_periods > 0:
    the odometry of that many ticks before (the first one until then), still stamped with the tick."""

    def __init__(self, latency_periods: int = 0):
        if latency_periods < 0:
            raise ValueError(f'latency_periods = {latency_periods!r} must be >= 0')
        self.queue = collections.deque(maxlen=int(latency_periods) + 1)

    def observe(self, t_ns: int, plant):
        self.queue.append(plant.observed())

    def seen(self, t_ns: int):
        return (t_ns, self.queue[0]) if self.queue else None


class FixedAge:
    """The plant's odometry age_s before the tick, interpolated between the ticks' states (a 30 ms age is not
    rounded to a 10 ms tick; before the first tick: the first state), stamped when it was measured."""

    def __init__(self, age_s: float):
        if not (math.isfinite(age_s) and age_s >= 0.0):
            raise ValueError(f'telemetry age = {age_s!r} s must be a finite number >= 0')
        self.age_ns = round(age_s * 1e9)
        self.times_ns, self.states = [], []

    def observe(self, t_ns: int, plant):
        self.times_ns.append(t_ns)
        self.states.append(plant.observed())

    def seen(self, t_ns: int):
        return (t_ns - self.age_ns, state_at(self.times_ns, self.states, t_ns - self.age_ns)) if self.states else None


def state_at(times_ns, states, t_ns) -> State:
    """The state at t_ns, interpolated between the recorded states (the first before them, the last after)."""
    j = int(np.searchsorted(times_ns, t_ns, side='right'))
    if j == 0:
        return states[0]
    if j == len(times_ns) or t_ns <= times_ns[j - 1]:
        return states[j - 1]
    a, b = states[j - 1], states[j]
    w = (t_ns - times_ns[j - 1]) / (times_ns[j] - times_ns[j - 1])
    q = (1 - w) * a.quaternion + w * (b.quaternion if a.quaternion @ b.quaternion >= 0 else -b.quaternion)
    return State(position=(1 - w) * a.position + w * b.position, velocity=(1 - w) * a.velocity + w * b.velocity,
                 quaternion=q / np.linalg.norm(q), body_rates=(1 - w) * a.body_rates + w * b.body_rates)


class DelayLine:
    """A vehicle's telemetry: the plant's odometry sampled every `every_periods` ticks, delivered latency_s after
    it was measured (stamped then), released in bursts up to burst_s apart (uniform, seeded: how the emulated
    ArduPilot sends it; between bursts the controller keeps the last one released). `initial`: a sample of the
    state at rest since before the first tick (the controller has odometry from the start). The odometry's stamp:
    when it was measured + stamp_shift_s (latency_s: when it arrived, as a receiver stamping on receipt; negative:
    stamped early, as a clock mapping that runs ahead)."""

    def __init__(self, latency_s: float, every_periods: int = 1, burst_s: float = 0.0, seed: int = 0,
                 initial: State | None = None, stamp_shift_s: float = 0.0):
        if not (math.isfinite(latency_s) and latency_s >= 0.0):
            raise ValueError(f'telemetry latency = {latency_s!r} s must be a finite number >= 0')
        if not (math.isfinite(burst_s) and burst_s >= 0.0):
            raise ValueError(f'telemetry burst = {burst_s!r} s must be a finite number >= 0')
        if every_periods < 1:
            raise ValueError(f'every_periods = {every_periods!r} must be >= 1')
        self.latency_ns = round(latency_s * 1e9)
        self.stamp_shift_ns = round(stamp_shift_s * 1e9)
        self.every = int(every_periods)
        self.burst_ns = round(burst_s * 1e9)
        self.rng = np.random.default_rng(seed)
        self.samples = collections.deque()
        if initial is not None:
            self.samples.append((-self.latency_ns, initial))
        self.observed = 0
        self.released = None
        self.next_burst_ns = None

    def observe(self, t_ns: int, plant):
        if self.observed % self.every == 0:
            self.samples.append((t_ns, plant.observed()))
        self.observed += 1

    def seen(self, t_ns: int):
        if self.next_burst_ns is not None and t_ns < self.next_burst_ns:
            return self.released
        while len(self.samples) > 1 and self.samples[1][0] <= t_ns - self.latency_ns:
            self.samples.popleft()
        if self.samples and self.samples[0][0] <= t_ns - self.latency_ns:
            measured_ns, state = self.samples[0]
            self.released = (measured_ns + self.stamp_shift_ns, state)
        if self.burst_ns:
            self.next_burst_ns = t_ns + round(float(self.rng.uniform(0.0, self.burst_ns)))
        return self.released


class Mocap:
    """position_controller on motion capture (state_source external_pose): the plant's truth measured by the
    simulator's motion-capture stand-in (quad_sim.mocap: frames at its rate, noise, latency, lost frames), each new
    pose through the controller's velocity filter (quad_control.pose_state), stamped when measured."""

    def __init__(self, config: MocapConfig, pose_filter: PoseStateFilter, seed: int = 0):
        self.mocap = MotionCapture(config, seed)
        self.filter = pose_filter
        self.newest = None

    def observe(self, t_ns: int, plant):
        truth = plant.state
        for frame in self.mocap.offer(t_ns, truth.position, truth.quaternion):
            self.newest = (frame.stamp_ns, self.filter.update(frame.stamp_ns, frame.position, frame.quaternion))

    def seen(self, t_ns: int):
        return self.newest


def idle(state: State) -> AttitudeSetpoint:
    """Level at the vehicle's yaw, hover thrust: what the plant flies before the controller's first setpoint."""
    return AttitudeSetpoint(quaternion=rotations.from_yaw(float(rotations.to_euler(state.quaternion)[2])),
                            specific_force_mps2=GRAVITY_MPS2)


@dataclass
class Flown:
    """A flight through `fly`: the truth at every tick and after the last period (`final`; None when the flight
    ended early), the ticks' outputs (None where a tick gave no setpoint), the odometry the controller took
    (stamp_ns, State), and why it stopped early."""
    t_ns: list = field(default_factory=list)
    truth: list = field(default_factory=list)
    final: State | None = None
    final_ns: int | None = None
    ticks: list = field(default_factory=list)
    odometry: list = field(default_factory=list)
    stopped: str | None = None
    done: bool = False

    def t_s_array(self) -> np.ndarray:
        """The tick times (s)."""
        return np.array(self.t_ns, dtype=float) * 1e-9

    def saturated_ticks(self) -> int:
        """Ticks whose setpoint had its thrust or tilt clamped."""
        return sum(bool(t.saturation.thrust or t.saturation.tilt) for t in self.ticks if t is not None)

    def track(self) -> tuple[np.ndarray, list]:
        """(t_s, truth) of every tick and, when the flight ran to its end, after the last period."""
        times_ns, states = list(self.t_ns), list(self.truth)
        if self.final is not None:
            times_ns.append(self.final_ns)
            states.append(self.final)
        return np.array(times_ns, dtype=float) * 1e-9, states


class ClosedLoop:
    """One vehicle's closed loop a period at a time: `fly` runs one; quad_bringup.offline.fleet_loop steps many in
    lockstep (every vehicle's control, then every plant's physics, then the contacts between them)."""

    def __init__(self, loop: ControlLoop, plant, telemetry, on_tick=None):
        self.loop, self.plant, self.telemetry, self.on_tick = loop, plant, telemetry, on_tick
        self.flown = Flown()
        self.setpoint = None        # the newest setpoint the plant flies
        self._newest_ns = None      # the stamp of the newest odometry the loop took

    def record(self, t_ns: int) -> State:
        """The truth at t_ns, kept in the flight's track."""
        truth = self.plant.state
        self.flown.t_ns.append(t_ns)
        self.flown.truth.append(truth)
        return truth

    def control(self, t_ns: int) -> bool:
        """The tick at t_ns (the module docstring); False when the flight ends here (a lockstep tick without a
        setpoint: the graph's controller would never answer)."""
        self.telemetry.observe(t_ns, self.plant)
        seen = self.telemetry.seen(t_ns)
        loop = self.loop
        if loop.lockstep:
            loop.tick(t_ns)
            tick = None if seen is None else loop.set_odometry(*seen)
            taken = seen is not None
        else:
            taken = seen is not None and (self._newest_ns is None or seen[0] > self._newest_ns)
            if taken:
                self._newest_ns = seen[0]
                loop.set_odometry(*seen)
            tick = loop.tick(t_ns)
        if taken:
            self.flown.odometry.append(seen)
        self.flown.ticks.append(tick)
        if self.on_tick is not None:
            self.on_tick(t_ns, seen, tick)
        if tick is not None:
            self.setpoint = tick.setpoint
        elif loop.lockstep:
            self.flown.stopped = loop.dead or f'no setpoint at t = {t_ns * 1e-9:.3f} s'
            return False
        elif self.setpoint is None:
            self.setpoint = idle(self.plant.state)
        else:
            return True     # nothing new: the plant flies the last setpoint on
        self.plant.command(self.setpoint)
        return True

    def advance(self, dt_s: float) -> bool:
        """The plant's physics over dt_s; False when it stopped (the reason in flown.stopped)."""
        try:
            self.plant.advance(dt_s)
        except SimulationStopped as exc:
            self.flown.stopped = str(exc)
            return False
        return True


def fly(loop: ControlLoop, plant, telemetry, periods: int, *, start_ns: int = 0, done=None, fault=None,
        on_tick=None) -> Flown:
    """Flies `periods` periods of 1 / loop.rate_hz (the module docstring). done(t_ns, truth) -> bool ends the
    flight there (completed); fault(t_ns, truth) -> reason or None ends it as stopped; on_tick(t_ns, seen, tick)
    sees each tick's odometry and output (a bag, a log)."""
    period_ns = round(1e9 / loop.rate_hz)
    closed = ClosedLoop(loop, plant, telemetry, on_tick)
    out = closed.flown
    for k in range(periods):
        t_ns = start_ns + k * period_ns
        truth = closed.record(t_ns)
        if done is not None and done(t_ns, truth):
            out.done = True
            return out
        out.stopped = fault(t_ns, truth) if fault is not None else None
        if out.stopped or not closed.control(t_ns) or not closed.advance(period_ns * 1e-9):
            return out
    out.final, out.final_ns = plant.state, start_ns + periods * period_ns
    return out
