"""The flight loop without ROS, for tuning: quad_sim's Simulator + quad_control's ControlLoop (the one
position_controller runs: hold before the plan, dt clamp, reset at the plan's start, start-step guard, lockstep
deferral) at the controller rate, tracking the mission's plan sampled as the trajectory node publishes it.

The lockstep graph's timing: at tick t_k the simulator's odometry stamped t_k arrives, the loop's tick at t_k
runs with it, and its setpoint is held for one period; minus DDS, processes and the bag. Importable with
numpy/scipy (and PyYAML) alone. The metrics come from quad_bringup.metrics, the report's own definitions, so
the numbers are defined exactly as `quadflight fly` reports them.
"""

from dataclasses import dataclass, field

import numpy as np

from quad_bringup.metrics import Completion, Flight, compute_metrics
from quad_common import rotations
from quad_common.paths import resolve_config
from quad_control.loop import MAX_START_STEP_M, RATE_HZ, ControlLoop
from quad_control.position import Limits, PositionController, PositionGains
from quad_sim.disturbances import load_profile
from quad_sim.simulator import SimulationStopped, Simulator
from quad_trajectory.mission import load_mission, plan_mission

DISTURBANCES_FILE = resolve_config('config/disturbances.yaml')  # installed share, else the checkout
SAMPLE_RATE_HZ = 100.0   # config/trajectory.yaml sample_rate_hz


@dataclass
class LoopOptions:
    controller: str = 'pd'
    gains: PositionGains | None = None          # None: the seed's
    speed_mps: float | None = None              # None: the mission's
    plan_overrides: dict | None = None          # PlanOptions fields (e.g. time_allocation='limits')
    disturbances: str = 'none'
    rate_hz: float = RATE_HZ
    physics_rate_hz: float = 1000.0
    time_limit_factor: float = 3.0
    rule: Completion = Completion()
    start_delay_s: float = 0.0                  # the plan starts this long after t = 0 (held before)
    max_start_step_m: float = MAX_START_STEP_M


@dataclass
class OfflineRun:
    """One offline flight: the report's metrics and what each tick saw and commanded."""
    metrics: dict
    t_s: np.ndarray = field(default_factory=lambda: np.zeros(0))              # tick times
    setpoints: list = field(default_factory=list)                             # AttitudeSetpoint per tick
    references: list = field(default_factory=list)                            # Reference per tick
    loop: ControlLoop | None = None


def fly_offline(mission_path, options: LoopOptions | None = None) -> dict:
    """Plans and flies one mission; returns the report's metrics (plus 'stopped' when the sim gave up)."""
    return run_offline(mission_path, options).metrics


def plan_offline(mission_path, options: LoopOptions | None = None):
    """(mission, plan, trajectory sampled as trajectory_node publishes it)."""
    options = options or LoopOptions()
    mission = load_mission(mission_path)
    plan = plan_mission(mission, speed_mps=options.speed_mps, **(options.plan_overrides or {}))
    return mission, plan, plan.trajectory.to_sampled(SAMPLE_RATE_HZ)


def make_simulator(mission, trajectory, options: LoopOptions) -> Simulator:
    """The simulator as fly starts it: at the mission's initial position, facing the plan's first yaw."""
    profile = load_profile(DISTURBANCES_FILE, options.disturbances)
    return Simulator(mission.vehicle, options.physics_rate_hz, initial_position=mission.initial_position,
                     initial_yaw=float(trajectory.position[0, 3]), disturbances=profile, world=mission.world,
                     robot_radius_m=mission.options.robot_radius_m)


def run_offline(mission_path, options: LoopOptions | None = None) -> OfflineRun:
    """fly_offline, keeping the per-tick setpoints and references."""
    options = options or LoopOptions()
    mission, plan, trajectory = plan_offline(mission_path, options)
    sim = make_simulator(mission, trajectory, options)
    controller = PositionController(options.controller, options.gains or PositionGains(), mission.vehicle,
                                    Limits.of(mission.vehicle))
    loop = ControlLoop(controller, options.rate_hz, lockstep=True, max_start_step_m=options.max_start_step_m)
    period_ns = round(1e9 / options.rate_hz)
    start_ns = round(options.start_delay_s * 1e9)
    loop.set_trajectory(start_ns, trajectory)
    arrival_s = options.rule.plan_arrival_s(trajectory)
    end_s = options.time_limit_factor * trajectory.duration_s + 10.0 + options.start_delay_s
    times, positions, velocities, eulers, ticks = [], [], [], [], []
    stopped = None
    for k in range(int(end_s * options.rate_hz) + 1):
        t_ns = k * period_ns
        t_s = t_ns * 1e-9
        truth = sim.state
        times.append(t_s)
        positions.append(truth.position)
        velocities.append(truth.velocity)
        eulers.append(rotations.to_euler(truth.quaternion))
        if options.rule.done(t_s - options.start_delay_s, truth.position, truth.velocity, trajectory, arrival_s):
            break
        loop.tick(t_ns)                                   # the tick at t_k waits for its odometry ...
        tick = loop.set_odometry(t_ns, sim.odometry_state())  # ... stamped t_k, and runs with it
        if tick is None:
            stopped = f'no setpoint at t = {t_s:.3f} s'
            break
        ticks.append(tick)
        sim.set_setpoint(tick.setpoint)
        try:
            sim.advance(period_ns * 1e-9)
        except SimulationStopped as exc:
            stopped = str(exc)
            break
    collision = next((e.time_s for e in sim.events if e.kind == 'collision'), None)
    flight = Flight(odom_t=np.array(times), position=np.array(positions), velocity=np.array(velocities),
                    euler=np.array(eulers), traj_start_s=options.start_delay_s, trajectory=trajectory,
                    waypoints=plan.waypoints, collision_time_s=collision)
    metrics = compute_metrics(flight, options.rule)
    if stopped:
        metrics['stopped'] = stopped
    return OfflineRun(metrics, np.array([t.t_ns * 1e-9 for t in ticks]), [t.setpoint for t in ticks],
                      [t.reference for t in ticks], loop)
