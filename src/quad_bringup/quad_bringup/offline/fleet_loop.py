"""A fleet's flight without ROS: every vehicle's Simulator and ControlLoop (the flight harness's ClosedLoop, as
closed_loop flies one) stepped in lockstep at the controller rate, with vehicle-vehicle collisions (robot radii)
reported as events like the simulator's obstacle collisions.

Each tick t_k: every vehicle's loop runs with its odometry stamped t_k (closed_loop.run_offline's tick), then every
simulator advances one controller period (its compiled physics, failsafe, floor and world checks unchanged).
Stepping: a loop over Simulator instances. A numpy core vectorized over vehicles costs ~40 array operations per
RK4 stage whatever N is; bench/bench_fleet.py measures both (docs/benchmarks.md, bench_fleet): at 1 kHz the loop
over compiled Simulators is faster up to 64 vehicles, and the controllers (Python) cost more than the physics.

Vehicle-vehicle collisions: quad_sim.vehicle_contact (the simulator node's fleet mode checks them the same way); the
flight goes on, as with obstacles, and the vehicle's metrics say it collided.
"""

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from quad_bringup.analysis.metrics import Flight, compute_metrics
from quad_bringup.offline.closed_loop import (
    SAMPLE_RATE_HZ,
    LoopOptions,
    controller_vehicle,
    load_control_profile,
    make_simulator,
)
from quad_bringup.offline.harness import ClosedLoop, Fresh, SimulatorPlant
from quad_common import rotations
from quad_control.loop import ControlLoop
from quad_control.plugins import make_controller
from quad_control.position import Limits, PositionGains
from quad_sim.vehicle_contact import VEHICLE_COLLISION, VehicleContacts
from quad_trajectory.fleet import Fleet, FleetPlan, load_fleet, plan_fleet


@dataclass
class FleetRun:
    """One fleet flight: each vehicle's metrics (the report's), the collisions and the flown separation."""
    names: list
    metrics: dict                          # name -> metrics (plus 'stopped' where its simulator gave up)
    events: list                           # (name, simulator Event) of every vehicle, in time order
    collisions: list                       # (time_s, a, b, distance_m) of each vehicle-vehicle collision start
    t_s: np.ndarray                        # tick times
    min_separation_m: np.ndarray           # the fleet's smallest pairwise distance at each tick
    plan: FleetPlan | None = None
    wall_s: dict = field(default_factory=dict)   # control, physics, collision, total
    positions: dict = field(default_factory=dict)   # name -> (ticks, 3) flown positions at t_s
    controllers: dict = field(default_factory=dict)  # name -> the controller it flew (pd, pid, se3)
    finish: Callable | None = None         # draws the vehicles' report figures (fleet_graph, figures=True)

    @property
    def sim_s(self) -> float:
        return float(self.t_s[-1]) if len(self.t_s) else 0.0

    @property
    def real_time_factor(self) -> float:
        return self.sim_s / self.wall_s['total'] if self.wall_s.get('total') else float('inf')

    def closest(self) -> tuple:
        """(distance_m, time_s) of the closest approach flown."""
        if not len(self.min_separation_m):
            return float('inf'), 0.0
        k = int(np.argmin(self.min_separation_m))
        return float(self.min_separation_m[k]), float(self.t_s[k])


class _Vehicle:
    """One fleet vehicle: its simulator and its closed loop (quad_bringup.offline.harness.ClosedLoop: closed_loop's
    lockstep tick, the loop's tick at t_k with the odometry stamped t_k) and what it flew."""

    def __init__(self, fv, plan, delay_s, index, options: LoopOptions):
        controller, gains = options.controller, options.gains or PositionGains()
        if fv.profile_path:
            controller, gains = load_control_profile(fv.profile_path)
        controller = fv.controller or controller
        self.options = dataclasses.replace(options, controller=controller, gains=gains, start_delay_s=delay_s,
                                           seed=options.seed + index)
        self.name, self.radius_m, self.plan = fv.name, fv.radius_m, plan
        self.trajectory = plan.trajectory.to_sampled(SAMPLE_RATE_HZ)
        self.sim = make_simulator(fv.mission, self.trajectory, self.options)
        vehicle = controller_vehicle(fv.mission, self.options)
        self.loop = ControlLoop(make_controller(controller, gains, vehicle, Limits.of(vehicle), options.rate_hz),
                                options.rate_hz, lockstep=True, max_start_step_m=options.max_start_step_m)
        self.loop.set_trajectory(round(delay_s * 1e9), self.trajectory)
        self.arrival_s = options.rule.plan_arrival_s(self.trajectory)
        self.closed = ClosedLoop(self.loop, SimulatorPlant(self.sim),
                                 Fresh(round(options.odom_latency_s * options.rate_hz)))
        self.done_s = None

    @property
    def stopped(self) -> str | None:
        return self.closed.flown.stopped

    def record(self, t_ns):
        truth = self.closed.record(t_ns)
        t_s = t_ns * 1e-9
        elapsed = t_s - self.options.start_delay_s
        if self.done_s is None and elapsed >= self.arrival_s and self.options.rule.done(
                elapsed, truth.position, truth.velocity, self.trajectory, self.arrival_s):
            self.done_s = t_s

    def positions(self) -> np.ndarray:
        return np.array([s.position for s in self.closed.flown.truth])

    def metrics(self) -> dict:
        collision = next((e.time_s for e in self.sim.events if e.kind in ('collision', VEHICLE_COLLISION)), None)
        flown = self.closed.flown
        truth = flown.truth
        flight = Flight(odom_t=flown.t_s_array(), position=self.positions(),
                        velocity=np.array([s.velocity for s in truth]),
                        euler=rotations.to_euler(np.array([s.quaternion for s in truth])),
                        traj_start_s=self.options.start_delay_s, trajectory=self.trajectory,
                        waypoints=self.plan.waypoints, collision_time_s=collision)
        m = compute_metrics(flight, self.options.rule)
        m['vehicle_collisions'] = sum(e.kind == VEHICLE_COLLISION for e in self.sim.events)
        m['saturated_s'] = self.sim.saturated_steps * self.sim.step_s   # as closed_loop.run_offline reports them
        m['saturated_fraction'] = flown.saturated_ticks() / max(len(truth) - 1, 1)
        if self.stopped:
            m['stopped'] = self.stopped
        return m


def fly_fleet(fleet: Fleet | str, options: LoopOptions | None = None, fleet_plan: FleetPlan | None = None,
              refuse_conflicts: bool = True, controller_stops: dict | None = None) -> FleetRun:
    """Plans the fleet (plan_fleet: separation checked, deconflicted where the file asks) and flies every vehicle in
    lockstep until all have completed (the vehicle's completion rule; done vehicles hold their end) or the time
    limit (time_limit_factor x the longest plan + its delay + 10 s). Raises ValueError with the refusal line when
    the plan has a separation conflict, unless refuse_conflicts is False. controller_stops {name: t_s}: that
    vehicle's controller dies at t_s (no more setpoints): its simulator's failsafe lands it, the others fly on; it
    is done once disarmed on the floor."""
    options = options or LoopOptions()
    fleet = load_fleet(fleet) if isinstance(fleet, str) or hasattr(fleet, '__fspath__') else fleet
    fleet_plan = fleet_plan or plan_fleet(fleet, speed_mps=options.speed_mps, **(options.plan_overrides or {}))
    if refuse_conflicts and fleet_plan.refusal():
        raise ValueError(fleet_plan.refusal())
    vehicles = [_Vehicle(fv, plan, delay, k, options) for k, (fv, plan, delay) in
                enumerate(zip(fleet.vehicles, fleet_plan.plans, fleet_plan.delays_s))]
    stops = dict(controller_stops or {})
    unknown = sorted(set(stops) - {v.name for v in vehicles})
    if unknown:
        raise ValueError(f'controller_stops: {unknown[0]!r} is not a vehicle of {fleet.name}')
    contacts = VehicleContacts([v.name for v in vehicles], [v.sim for v in vehicles], [v.radius_m for v in vehicles])
    period_ns = round(1e9 / options.rate_hz)
    end_s = max(options.time_limit_factor * v.trajectory.duration_s + 10.0 + v.options.start_delay_s
                for v in vehicles)
    vehicles[0].sim.warm_up()     # load the compiled kernels before the clock starts (wall_s is the flight's)
    wall = dict.fromkeys(('control', 'physics', 'collision'), 0.0)
    start_wall = time.perf_counter()
    ticks, separations = [], []
    for k in range(int(end_s * options.rate_hz) + 1):
        t_ns = k * period_ns
        t_s = t_ns * 1e-9
        for v in vehicles:
            v.record(t_ns)
        ticks.append(t_s)
        if all(v.done_s is not None or v.stopped or (v.name in stops and not v.sim.armed) for v in vehicles):
            separations.append(_min_distance(contacts.positions()))
            break
        w0 = time.perf_counter()
        for v in vehicles:
            if not v.stopped and not t_s >= stops.get(v.name, np.inf):
                v.closed.control(t_ns)
        w1 = time.perf_counter()
        for v in vehicles:
            if not v.stopped:
                v.closed.advance(period_ns * 1e-9)
        w2 = time.perf_counter()
        separations.append(contacts.step(t_s, period_ns * 1e-9))
        wall['control'] += w1 - w0
        wall['physics'] += w2 - w1
        wall['collision'] += time.perf_counter() - w2
    wall['total'] = time.perf_counter() - start_wall
    events = sorted(((v.name, e) for v in vehicles for e in v.sim.events), key=lambda x: x[1].time_s)
    return FleetRun([v.name for v in vehicles], {v.name: v.metrics() for v in vehicles}, events, contacts.collisions,
                    np.array(ticks), np.array(separations[:len(ticks)]), fleet_plan, wall,
                    {v.name: v.positions() for v in vehicles},
                    {v.name: v.loop.controller.name for v in vehicles})


def _min_distance(p) -> float:
    n = len(p)
    if n < 2:
        return float('inf')
    i, j = np.triu_indices(n, 1)
    return float(np.min(np.linalg.norm(p[j] - p[i], axis=1)))
