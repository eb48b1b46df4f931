"""Mission files (docs/missions.md): waypoints, yaw, trajectory options, vehicle and world.

`load_mission(path)` validates the file (errors name the file, the field and the value) and resolves
paths inside it relative to the file; `plan_mission(mission)` plans it. The `quadflight plan/fly`
commands and the trajectory node all go through these two functions.
"""

import dataclasses
import os
from dataclasses import dataclass, field

import numpy as np

from quad_common.vehicle import Vehicle, load_vehicle
from quad_common.world import World, load_world
from quad_common.yaml_io import load_yaml
from quad_trajectory import feasibility, planner
from quad_trajectory.mission_file import (  # noqa: F401  (DEFAULT_*_PATH, SEED_CONTROL_POINTS: re-exported)
    DEFAULT_MISSION_PATH,
    DEFAULT_VEHICLE_PATH,
    IF_INFEASIBLE,
    MISSION_KEYS,
    SEED_CONTROL_POINTS,
    mission_fields,
    relative_path,
)

SAMPLE_RATE_HZ = 100.0   # points per second of the published plan: trajectory_node's and the offline loop's default


@dataclass
class Mission:
    path: str
    name: str
    waypoints: np.ndarray                 # (N, 3) as written (merging happens when planning)
    yaw: object                           # None, one number, or one per waypoint
    options: planner.PlanOptions
    vehicle: Vehicle | None
    vehicle_path: str | None
    world: World | None = None
    world_path: str | None = None
    extra: dict = field(default_factory=dict)   # top-level keys owned by other tools (fly, sim)
    if_infeasible: str = 'refuse'               # trajectory.if_infeasible: refuse, or fly fastest / limits

    @property
    def initial_position(self) -> np.ndarray:
        """Where the vehicle starts: the first waypoint."""
        return self.waypoints[0].copy()


def mission_from_dict(data: dict, path: str = 'mission', fields: dict | None = None) -> Mission:
    """Validated Mission from a parsed mission file (its own values: quad_trajectory.mission_file.mission_fields,
    or `fields` where the caller has them already; here the vehicle, what the options need of it, and the world);
    relative paths are taken relative to `path`."""
    fields = mission_fields(data, path) if fields is None else fields
    traj, options, vehicle_path = fields['trajectory'], fields['options'], fields['vehicle_path']
    try:
        vehicle = load_vehicle(vehicle_path) if vehicle_path else None
        planner.validate_options(options, vehicle)
        world_path = relative_path(path, data['world'], 'world') if data.get('world') is not None else None
        world = load_world(world_path) if world_path else None
    except ValueError as exc:
        raise ValueError(f'{path}: {exc}') from None
    if_infeasible = traj.get('if_infeasible', 'refuse')
    if if_infeasible not in IF_INFEASIBLE:
        raise ValueError(f'{path}: trajectory.if_infeasible = {if_infeasible!r} must be one of '
                         f'{", ".join(IF_INFEASIBLE)}')
    known = MISSION_KEYS
    return Mission(path=path, name=str(data.get('name', os.path.splitext(os.path.basename(path))[0])),
                   waypoints=np.asarray(fields['waypoints'], dtype=float), yaw=fields['yaw'], options=options,
                   vehicle=vehicle, vehicle_path=vehicle_path,
                   world=world, world_path=world_path, extra={k: v for k, v in data.items() if k not in known},
                   if_infeasible=if_infeasible)


def load_mission(path) -> Mission:
    path = os.fspath(path)
    return mission_from_dict(load_yaml(path), path)


def plan_mission(mission: Mission, speed_mps: float | None = None, **overrides) -> planner.PlanResult:
    """Plan the mission; speed_mps and any PlanOptions field given override the file's values."""
    if speed_mps is not None:
        overrides['speed_mps'] = speed_mps
    unknown = set(overrides) - {f.name for f in dataclasses.fields(planner.PlanOptions)}
    if unknown:
        raise ValueError(f'plan_mission: unknown option {sorted(unknown)[0]!r}')
    options = dataclasses.replace(mission.options, **overrides)
    try:
        return planner.plan(mission.waypoints, mission.yaw, options, world=mission.world, vehicle=mission.vehicle)
    except ValueError as exc:
        raise ValueError(f'{mission.path}: {exc}') from None


def preflight(mission, result, vehicle=None, speed_mps=None) -> feasibility.Preflight:
    """Check `result` (plan_mission's) on `vehicle` (default the mission's); when it fails, plan the
    mission with time_allocation fastest (and limits) and keep each that passes the same check."""
    vehicle = vehicle or mission.vehicle
    o = result.options
    report = feasibility.Preflight(feasibility.check(result.trajectory, vehicle), o.time_allocation, o.speed_mps,
                                   result.trajectory.duration_s)
    if report.ok:
        return report
    for name in ('fastest', 'limits'):
        if name == o.time_allocation:
            continue
        try:
            alt = plan_mission(dataclasses.replace(mission, vehicle=vehicle), speed_mps=speed_mps, time_allocation=name)
        except ValueError:
            continue
        if feasibility.check(alt.trajectory, vehicle).ok:
            note = (f' (as fast as {vehicle.name} flies it with {100 * alt.options.margin:g} % of each limit to spare)'
                    if name == 'fastest' else '')
            report.alternatives.append((name, alt.trajectory.duration_s, note))
    return report
