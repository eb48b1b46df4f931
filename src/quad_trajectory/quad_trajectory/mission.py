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
from quad_common.yaml_io import load_yaml, refuse_number_text, refuse_typos, suggestion
from quad_trajectory import feasibility, planner

SEED_CONTROL_POINTS = (0.1, 0.9)
SAMPLE_RATE_HZ = 100.0   # points per second of the published plan: trajectory_node's and the offline loop's default
_REPO_CONFIG = os.path.join(os.path.dirname(os.path.realpath(__file__)), '..', '..', '..', 'config')
DEFAULT_VEHICLE_PATH = os.path.normpath(os.path.join(_REPO_CONFIG, 'vehicles', 'crazyflie.yaml'))
DEFAULT_MISSION_PATH = os.path.normpath(os.path.join(_REPO_CONFIG, 'missions', 'maze.yaml'))
_TRAJECTORY_KEYS = {'method', 'waypoint_constraint', 'speed', 'time_allocation', 'control_points', 'limits',
                    'avoid_collisions', 'rho', 'margin', 'if_infeasible', 'generator', 'generator_args',
                    'generator_waypoints', 'duration_s'}
# what fly does with a plan the vehicle cannot fly (quad_trajectory.feasibility): refuse it, or fly that allocation
IF_INFEASIBLE = ('refuse', 'fastest', 'limits')
_LIMIT_KEYS = {'v_max_mps', 'a_max_mps2'}


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


def _relative(base_file, value, key):
    if not isinstance(value, str) or not value:
        raise ValueError(f'{base_file}: {key} = {value!r} must be a file path (relative to the mission file)')
    return os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(base_file)), value))


def _control_points(value, path):
    if value is None or value is False:
        return ()
    if value is True:
        return SEED_CONTROL_POINTS
    if isinstance(value, list):
        return tuple(value)
    raise ValueError(f'{path}: trajectory.control_points = {value!r} must be true, false or a list of fractions')


MISSION_KEYS = frozenset({'name', 'waypoints', 'yaw', 'trajectory', 'vehicle', 'world', 'robot_radius_m'})


def mission_from_dict(data: dict, path: str = 'mission') -> Mission:
    """Validated Mission from a parsed mission file; relative paths are taken relative to `path`."""
    if 'vehicles' in data:   # never fly one vehicle of a fleet (or its shared path) by mistake
        raise ValueError(f'{path}: a fleet mission (it has vehicles:): `quadflight plan` plans it and '
                         'quad_bringup.offline.fleet_loop.fly_fleet flies it offline; one-vehicle commands '
                         'do not take it')
    refuse_typos(data, MISSION_KEYS, path)
    refuse_number_text(data, ('robot_radius_m',), f'{path}: ')
    traj = data.get('trajectory') or {}
    if not isinstance(traj, dict):
        raise ValueError(f'{path}: trajectory = {traj!r} must be a mapping')
    refuse_number_text(traj, ('speed', 'rho', 'duration_s'), f'{path}: trajectory.')
    refuse_number_text(traj.get('limits') or {}, ('v_max_mps', 'a_max_mps2'), f'{path}: trajectory.limits.')
    unknown = sorted(set(traj) - _TRAJECTORY_KEYS)
    if unknown:
        raise ValueError(f'{path}: trajectory.{unknown[0]} is not a known key'
                         f'{suggestion(unknown[0], _TRAJECTORY_KEYS)} (known: {", ".join(sorted(_TRAJECTORY_KEYS))})')
    limits = traj.get('limits') or {}
    if not isinstance(limits, dict) or set(limits) - _LIMIT_KEYS:
        raise ValueError(f'{path}: trajectory.limits = {limits!r} may only hold {", ".join(sorted(_LIMIT_KEYS))}')
    try:
        if 'waypoints' not in data:
            raise ValueError('waypoints is missing')
        waypoints = planner.validate_waypoints(data['waypoints'])
        yaw = data.get('yaw')
        planner.validate_yaw(yaw, len(waypoints))
        defaults = planner.PlanOptions()
        options = planner.PlanOptions(
            method=traj.get('method', defaults.method),
            waypoint_constraint=traj.get('waypoint_constraint', defaults.waypoint_constraint),
            speed_mps=traj.get('speed', defaults.speed_mps),
            time_allocation=traj.get('time_allocation', defaults.time_allocation),
            control_points=_control_points(traj.get('control_points'), path),
            v_max_mps=limits.get('v_max_mps'), a_max_mps2=limits.get('a_max_mps2'), rho=traj.get('rho'),
            margin=traj.get('margin', defaults.margin),
            robot_radius_m=data.get('robot_radius_m', defaults.robot_radius_m),
            avoid_collisions=bool(traj.get('avoid_collisions', defaults.avoid_collisions)),
            generator=traj.get('generator', defaults.generator), generator_args=traj.get('generator_args'),
            generator_waypoints=traj.get('generator_waypoints', defaults.generator_waypoints),
            duration_s=traj.get('duration_s'))
        if 'vehicle' in data:
            vehicle_path = _relative(path, data['vehicle'], 'vehicle')
        else:
            vehicle_path = DEFAULT_VEHICLE_PATH if os.path.exists(DEFAULT_VEHICLE_PATH) else None
        vehicle = load_vehicle(vehicle_path) if vehicle_path else None
        planner.validate_options(options, vehicle)
        world_path = _relative(path, data['world'], 'world') if data.get('world') is not None else None
        world = load_world(world_path) if world_path else None
    except ValueError as exc:
        raise ValueError(f'{path}: {exc}') from None
    if_infeasible = traj.get('if_infeasible', 'refuse')
    if if_infeasible not in IF_INFEASIBLE:
        raise ValueError(f'{path}: trajectory.if_infeasible = {if_infeasible!r} must be one of '
                         f'{", ".join(IF_INFEASIBLE)}')
    known = MISSION_KEYS
    return Mission(path=path, name=str(data.get('name', os.path.splitext(os.path.basename(path))[0])),
                   waypoints=waypoints, yaw=yaw, options=options, vehicle=vehicle, vehicle_path=vehicle_path,
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
