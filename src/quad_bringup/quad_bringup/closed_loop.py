"""The flight loop without ROS, for tuning: quad_sim's Simulator + a quad_control PositionController at the
controller rate, tracking the mission's plan sampled as the trajectory node publishes it.

Same pieces and the same timing as the lockstep graph (at tick t_k the controller sees the odometry of t_k, its
setpoint is held for one period), minus DDS, processes and the bag; the metrics come from the report's own
`compute_metrics` on the simulated arrays, so the numbers are defined exactly as `quadflight fly` reports them.
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from quad_bringup.report import Completion, Flight, compute_metrics
from quad_common import rotations
from quad_common.paths import resolve_config
from quad_common.vehicle import load_vehicle
from quad_common.yaml_io import load_yaml
from quad_control.position import Limits, PositionController, PositionGains, gains_from_parameters
from quad_sim.disturbances import load_profile, profile_from_dict
from quad_sim.simulator import SimulationStopped, Simulator
from quad_trajectory.mission import DEFAULT_VEHICLE_PATH, load_mission, plan_mission

REPO_ROOT = Path(__file__).resolve().parents[3]
DISTURBANCES_FILE = REPO_ROOT / 'config' / 'disturbances.yaml'
SAMPLE_RATE_HZ = 100.0   # config/trajectory.yaml sample_rate_hz


@dataclass
class LoopOptions:
    controller: str = 'pd'
    gains: PositionGains | None = None          # None: the seed's
    speed_mps: float | None = None              # None: the mission's
    plan_overrides: dict | None = None          # PlanOptions fields (e.g. time_allocation='limits')
    disturbances: str | dict = 'none'           # a profile of config/disturbances.yaml, or one as a mapping
    plant: str | dict | None = None             # a plant family member (name or overrides) for the simulator only
    vehicle_path: str | None = None             # None: the mission's vehicle file
    seed: int = 0                               # the simulator's (gusts, odometry noise)
    rate_hz: float = 100.0
    physics_rate_hz: float = 1000.0
    time_limit_factor: float = 3.0
    rule: Completion = Completion()


def load_control_profile(path) -> tuple[str, PositionGains]:
    """(controller, gains) of a position_controller params file (config/control*.yaml) over the seed's."""
    values = (load_yaml(resolve_config(path)) or {}).get('position_controller', {}).get('ros__parameters', {})
    return values.get('controller', 'pd'), gains_from_parameters(values)


def fly_offline(mission_path, options: LoopOptions | None = None) -> dict:
    """Plans and flies one mission; returns the report's metrics (plus 'stopped' when the sim gave up)."""
    options = options or LoopOptions()
    mission = load_mission(mission_path)
    plan = plan_mission(mission, speed_mps=options.speed_mps, **(options.plan_overrides or {}))
    trajectory = plan.trajectory.to_sampled(SAMPLE_RATE_HZ)
    profile = (profile_from_dict({k: v for k, v in options.disturbances.items() if k != 'name'},
                                 options.disturbances.get('name', 'inline'))
               if isinstance(options.disturbances, dict) else load_profile(DISTURBANCES_FILE, options.disturbances))
    vehicle = load_vehicle(resolve_config(options.vehicle_path)) if options.vehicle_path else mission.vehicle
    plant_vehicle = load_vehicle(resolve_config(options.vehicle_path) if options.vehicle_path else
                                 mission.vehicle_path or DEFAULT_VEHICLE_PATH, plant=options.plant) \
        if options.plant else vehicle
    sim = Simulator(plant_vehicle, options.physics_rate_hz, initial_position=mission.initial_position,
                    initial_yaw=float(trajectory.position[0, 3]), disturbances=profile, world=mission.world,
                    robot_radius_m=mission.options.robot_radius_m, seed=options.seed)
    controller = PositionController(options.controller, options.gains or PositionGains(), vehicle,
                                    Limits.of(vehicle))
    period_s = 1.0 / options.rate_hz
    arrival_s = options.rule.plan_arrival_s(trajectory)
    end_s = options.time_limit_factor * trajectory.duration_s + 10.0
    times, positions, velocities, quaternions = [], [], [], []
    stopped = None
    saturated_ticks = 0
    for k in range(int(end_s * options.rate_hz) + 1):
        t_s = k * period_s
        truth = sim.state
        times.append(t_s)
        positions.append(truth.position)
        velocities.append(truth.velocity)
        quaternions.append(truth.quaternion)
        if t_s >= arrival_s and options.rule.done(t_s, truth.position, truth.velocity, trajectory, arrival_s):
            break
        ref = trajectory.reference(min(t_s, trajectory.duration_s))
        setpoint, saturation = controller.update(sim.odometry_state(), ref, period_s if k else 0.0)
        saturated_ticks += saturation.thrust or saturation.tilt
        sim.set_setpoint(setpoint)
        try:
            sim.advance(period_s)
        except SimulationStopped as exc:
            stopped = str(exc)
            break
    collision = next((e.time_s for e in sim.events if e.kind == 'collision'), None)
    flight = Flight(odom_t=np.array(times), position=np.array(positions), velocity=np.array(velocities),
                    euler=rotations.to_euler(np.array(quaternions)), traj_start_s=0.0, trajectory=trajectory,
                    waypoints=plan.waypoints, collision_time_s=collision)
    metrics = compute_metrics(flight, options.rule)
    metrics['saturated_fraction'] = saturated_ticks / max(len(times) - 1, 1)  # ticks with thrust or tilt clamped
    if stopped:
        metrics['stopped'] = stopped
    return metrics
