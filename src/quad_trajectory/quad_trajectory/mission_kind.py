"""Which kind of mission a file holds: a fleet (a `vehicles:` list, quad_trajectory.fleet) or one vehicle's
(quad_trajectory.mission). Pure Python (yaml only): the commands decide it before numpy is imported, so a refused
option costs no planner."""

import os

from quad_common.yaml_io import load_yaml


def is_fleet(data) -> bool:
    return isinstance(data, dict) and 'vehicles' in data


def is_fleet_file(path) -> bool:
    """True for a YAML mapping with a `vehicles` key (a fleet); False for anything else (left to load_mission)."""
    try:
        return is_fleet(load_yaml(os.fspath(path)))
    except ValueError:
        return False
