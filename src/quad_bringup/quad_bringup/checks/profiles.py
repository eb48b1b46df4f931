"""A control profile (`fly --control-profile`, a sweep's `profile:`) checked before anything starts:
one node key, `position_controller: ros__parameters:`, every key a parameter of position_controller, every value
of its type and within its declared range (quad_common.params.check_value, what the node itself refuses at
start-up). A typo, a vehicle file or a negative gain is refused naming the file, the key and the value."""

import difflib
from pathlib import Path

from quad_common.yaml_io import load_yaml

NODE = 'position_controller'
ROS_KEYS = frozenset({'use_sim_time'})   # rclpy's own parameters, allowed in any params file


def _specs() -> dict:
    from quad_control.parameters import SPECS

    return {spec.name: spec for spec in SPECS}


def _suggest(name, known) -> str:
    close = difflib.get_close_matches(name, known, n=1)
    return f' (did you mean {close[0]!r}?)' if close else ''


def check_control_profile(path) -> dict:
    """The profile's position_controller parameters; ValueError naming `path` and the first problem."""
    from quad_common.params import check_value

    path = Path(path)
    data = load_yaml(path) or {}
    if NODE not in data:
        if {'mass_kg', 'arm_length_m'} & set(data):
            raise ValueError(f'{path}: a vehicle file (mass_kg, arm_length_m), not a control profile: use it as '
                             '--vehicle; a profile holds position_controller: ros__parameters: {gains}')
        found = ', '.join(map(str, data)) or 'nothing'
        raise ValueError(f'{path}: not a control profile: no {NODE}: key (found {found})'
                         f'{_suggest(str(next(iter(data), "")), [NODE])}')
    unknown = set(data) - {NODE}
    if unknown:
        raise ValueError(f'{path}: unknown node key(s) {sorted(unknown)}: a control profile sets {NODE} only')
    node = data[NODE]
    if not isinstance(node, dict) or set(node) != {'ros__parameters'} or not isinstance(node['ros__parameters'],
                                                                                          dict):
        raise ValueError(f'{path}: {NODE}: must hold one key, ros__parameters: a mapping of its parameters')
    values = node['ros__parameters']
    specs = _specs()
    for key, value in values.items():
        if key in ROS_KEYS:
            continue
        spec = specs.get(key)
        if spec is None:
            raise ValueError(f'{path}: {key} = {value!r} refused: not a parameter of {NODE}'
                             f'{_suggest(key, list(specs))}')
        kind = bool if isinstance(spec.default, bool) else str if isinstance(spec.default, str) else (
            list if isinstance(spec.default, list) else (int, float))
        if not isinstance(value, kind) or (kind is not bool and isinstance(value, bool)):
            raise ValueError(f'{path}: {key} = {value!r} refused: must be a {type(spec.default).__name__}')
        reason = check_value(spec, value)
        if reason:
            raise ValueError(f'{path}: {reason}')
    return values
