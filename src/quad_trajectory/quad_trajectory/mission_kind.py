"""Which kind of mission a file holds: a fleet (a `vehicles:` list, quad_trajectory.fleet) or one vehicle's
(quad_trajectory.mission). Pure Python (yaml only): the commands decide it before numpy is imported, so a refused
option costs no planner."""

import os

from quad_common.yaml_io import load_yaml, refuse_typos

FLEET_KEYS = frozenset({'name', 'vehicles', 'waypoints', 'yaw', 'trajectory', 'vehicle', 'world', 'robot_radius_m',
                        'separation', 'autopilot'})


def is_fleet(data) -> bool:
    return isinstance(data, dict) and 'vehicles' in data


def is_fleet_file(path) -> bool:
    """True for a YAML mapping with a `vehicles` key (a fleet); False for anything else (left to load_mission)."""
    try:
        return is_fleet(load_yaml(os.fspath(path)))
    except ValueError:
        return False


def check_fleet_keys(data: dict, path: str = 'fleet'):
    """A fleet file's top-level keys (quad_trajectory.fleet.fleet_from_dict checks the rest): ValueError for a key
    that is not a fleet's, or for a one-vehicle mission (no `vehicles:`)."""
    refuse_typos(data, FLEET_KEYS, path)
    unknown = sorted(set(data) - FLEET_KEYS)
    if unknown:
        raise ValueError(f'{path}: {unknown[0]} = {data[unknown[0]]!r} is not a known fleet key '
                         f'(known: {", ".join(sorted(FLEET_KEYS))})')
    if 'vehicles' not in data:
        raise ValueError(f'{path}: not a fleet mission (no vehicles: list); `quadflight fly` flies a one-vehicle '
                         'mission')
