"""A mission file's own values (docs/missions.md) checked in pure Python (no numpy): its keys, waypoints, yaw,
trajectory options and the fields of its vehicle file, so a command refuses a bad mission before numpy is imported.
quad_trajectory.mission builds its Mission from what `mission_fields` returns (and checks what needs the Vehicle,
the world file or user code). Errors name the file, the field and the value."""

import os

from quad_common.vehicle_file import load_vehicle_fields
from quad_common.yaml_io import refuse_number_text, refuse_typos, suggestion
from quad_trajectory.plan_inputs import PlanOptions, check_option_values, waypoint_rows, yaw_values

SEED_CONTROL_POINTS = (0.1, 0.9)
_REPO_CONFIG = os.path.join(os.path.dirname(os.path.realpath(__file__)), '..', '..', '..', 'config')
DEFAULT_VEHICLE_PATH = os.path.normpath(os.path.join(_REPO_CONFIG, 'vehicles', 'crazyflie.yaml'))
DEFAULT_MISSION_PATH = os.path.normpath(os.path.join(_REPO_CONFIG, 'missions', 'maze.yaml'))
_TRAJECTORY_KEYS = {'method', 'waypoint_constraint', 'speed', 'time_allocation', 'control_points', 'limits',
                    'avoid_collisions', 'rho', 'margin', 'if_infeasible', 'generator', 'generator_args',
                    'generator_waypoints', 'duration_s'}
# what fly does with a plan the vehicle cannot fly (quad_trajectory.feasibility): refuse it, or fly that allocation
IF_INFEASIBLE = ('refuse', 'fastest', 'limits')
_LIMIT_KEYS = {'v_max_mps', 'a_max_mps2'}
MISSION_KEYS = frozenset({'name', 'waypoints', 'yaw', 'trajectory', 'vehicle', 'world', 'robot_radius_m'})


def relative_path(base_file, value, key):
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


def mission_fields(data: dict, path: str = 'mission') -> dict:
    """A parsed mission file's own values, checked: {'trajectory': its mapping, 'waypoints': [x, y, z] rows,
    'yaw': as written, 'options': PlanOptions, 'vehicle_path': the vehicle file (its fields checked) or None}.
    Relative paths are taken relative to `path`."""
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
        waypoints = waypoint_rows(data['waypoints'])
        yaw = data.get('yaw')
        yaw_values(yaw, len(waypoints))
        defaults = PlanOptions()
        options = PlanOptions(
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
            vehicle_path = relative_path(path, data['vehicle'], 'vehicle')
        else:
            vehicle_path = DEFAULT_VEHICLE_PATH if os.path.exists(DEFAULT_VEHICLE_PATH) else None
        if vehicle_path:
            load_vehicle_fields(vehicle_path)
        check_option_values(options)
    except ValueError as exc:
        raise ValueError(f'{path}: {exc}') from None
    return {'trajectory': traj, 'waypoints': waypoints, 'yaw': yaw, 'options': options, 'vehicle_path': vehicle_path}
