"""A vehicle file's rules (config/vehicles/*.yaml) and the plant family's overrides of its fields
(config/plant_family.yaml), in pure Python (floats, math.isfinite): `vehicle_fields` checks every field and
returns plain values, from which quad_common.vehicle builds its Vehicle; a command refuses a bad file with the same
function before numpy is imported. Errors name the file, the field and the value."""

import math

from quad_common.yaml_io import as_floats, load_yaml, refuse_typos

ATTITUDE_LOOPS = ('eq6', 'so3_pd', 'lag')
ATTITUDE_LOOP_KEYS = ('type', 'angle_p', 'rate_p', 'time_constant_s', 'use_feedforward_rates')
FIELDS = ('name', 'mass_kg', 'inertia_kgm2', 'arm_length_m', 'k_eta', 'k_m', 'rotor_speed_min_radps',
          'rotor_speed_max_radps', 'motor_time_constant_s', 'layout', 'max_tilt_deg', 'attitude_gains',
          'attitude_loop', 'mass_error', 'thrust_error')
OTHER_SECTIONS = ('aerodynamics', 'completion')   # read by other modules (quad_sim.disturbances, completion rule)
PLANT_FIELDS = ('motor_time_constant_s', 'attitude_gains', 'attitude_loop', 'mass_error', 'thrust_error')
PLANT_FAMILY_FILE = 'config/plant_family.yaml'


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _sequence(value) -> bool:
    """A list, a tuple or a 1-D array (not a string, not a mapping)."""
    return hasattr(value, '__len__') and not isinstance(value, (str, bytes, dict))


def _positive(data, key, path, allow_zero=False):
    value = data.get(key)
    if not (_is_number(value) and (value >= 0 if allow_zero else value > 0)):
        rule = '>= 0' if allow_zero else '> 0'
        raise ValueError(f'{path}: {key} = {value!r} must be a finite number {rule}')
    return float(value)


def _three(data, key, path):
    value = data[key]
    values = [value] * 3 if isinstance(value, (int, float)) else value
    if not (_sequence(values) and len(values) == 3
            and all(isinstance(v, (int, float)) and _is_number(v) and v > 0 for v in values)):
        raise ValueError(f'{path}: {key} = {value!r} must be three finite numbers > 0')
    return [float(v) for v in values]


def attitude_loop_fields(data, path='attitude_loop') -> dict:
    """The fields an `attitude_loop:` section sets ({} for none: the AttitudeLoop defaults), checked."""
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ValueError(f'{path} = {data!r} must be a mapping with a type ({", ".join(ATTITUDE_LOOPS)})')
    unknown = set(data) - set(ATTITUDE_LOOP_KEYS)
    if unknown:
        raise ValueError(f'{path}: unknown field(s) {sorted(unknown)}')
    kind = data.get('type', 'eq6')
    if kind not in ATTITUDE_LOOPS:
        raise ValueError(f'{path}.type = {kind!r} must be one of {", ".join(ATTITUDE_LOOPS)}')
    fields = {'type': kind, **{key: _three(data, key, path) for key in ('angle_p', 'rate_p') if key in data}}
    if 'time_constant_s' in data:
        fields['time_constant_s'] = _positive(data, 'time_constant_s', path)
    ff = data.get('use_feedforward_rates', True)
    if not isinstance(ff, bool):
        raise ValueError(f'{path}: use_feedforward_rates = {ff!r} must be true or false')
    fields['use_feedforward_rates'] = ff
    return fields


def _fraction(data, key, path):
    value = data.get(key, 0.0)
    if not (_is_number(value) and -0.5 <= value <= 1.0):
        raise ValueError(f'{path}: {key} = {value!r} must be a finite fraction in [-0.5, 1.0] (0.06 = +6 %)')
    return float(value)


def vehicle_fields(data: dict, path='vehicle') -> dict:
    """Every field of a vehicle file checked, as plain values (lists of floats for the per-axis ones; the
    attitude loop's fields as given); `extra`: the sections other modules read. Raises ValueError naming the
    field and the value."""
    inertia = data.get('inertia_kgm2')
    if (not isinstance(inertia, (list, tuple)) or len(inertia) != 3
            or not all(isinstance(v, (int, float)) and math.isfinite(v) and v > 0 for v in inertia)):
        raise ValueError(f'{path}: inertia_kgm2 = {inertia!r} must be three finite numbers > 0 (Ixx, Iyy, Izz)')
    gains = data.get('attitude_gains') or {}
    if not isinstance(gains, dict):
        raise ValueError(f'{path}: attitude_gains = {gains!r:.120} must be a mapping (kp, kd)')
    converted = {}
    for name, default in (('kp', 3000.0), ('kd', 300.0)):
        value = gains.get(name, [default] * 3)
        g = as_floats(value, 3)
        if g is None or not all(math.isfinite(v) and v >= 0 for v in g):
            raise ValueError(f'{path}: attitude_gains.{name} = {value!r:.120} must be three finite numbers >= 0')
        converted[name] = g
    layout = data.get('layout', 'x')
    if layout not in ('x', 'plus'):
        raise ValueError(f"{path}: layout = {layout!r} must be 'x' or 'plus'")
    refuse_typos(data, set(FIELDS) | set(OTHER_SECTIONS), str(path))
    fields = {
        'name': str(data.get('name', path)),
        'mass_kg': _positive(data, 'mass_kg', path),
        'inertia_kgm2': [float(v) for v in inertia],
        'arm_length_m': _positive(data, 'arm_length_m', path),
        'k_eta': _positive(data, 'k_eta', path),
        'k_m': _positive(data, 'k_m', path),
        'rotor_speed_min_radps': _positive(data, 'rotor_speed_min_radps', path, allow_zero=True),
        'rotor_speed_max_radps': _positive(data, 'rotor_speed_max_radps', path),
        'motor_time_constant_s': _positive(data, 'motor_time_constant_s', path, allow_zero=True)
        if 'motor_time_constant_s' in data else 0.0,
        'layout': layout,
        'max_tilt_deg': _positive(data, 'max_tilt_deg', path) if 'max_tilt_deg' in data else 35.0,
        'attitude_gains': converted,
        'attitude_loop': attitude_loop_fields(data.get('attitude_loop'), f'{path}: attitude_loop'),
        'mass_error': _fraction(data, 'mass_error', path),
        'thrust_error': _fraction(data, 'thrust_error', path),
        'extra': {k: val for k, val in data.items() if k not in FIELDS},
    }
    if fields['rotor_speed_min_radps'] >= fields['rotor_speed_max_radps']:
        raise ValueError(f'{path}: rotor_speed_min_radps = {fields["rotor_speed_min_radps"]} must be below '
                         f'rotor_speed_max_radps = {fields["rotor_speed_max_radps"]}')
    if fields['max_tilt_deg'] >= 90:
        raise ValueError(f'{path}: max_tilt_deg = {fields["max_tilt_deg"]} must be below 90')
    return fields


def load_plant_family(path=None) -> dict:
    """{member name: vehicle-file overrides} of config/plant_family.yaml (or `path`); each member checked."""
    from quad_common.paths import resolve_config
    path = resolve_config(path or PLANT_FAMILY_FILE)
    family = load_yaml(path)
    if not isinstance(family, dict) or not family:
        raise ValueError(f'{path}: must map member names to vehicle-field overrides')
    for name, member in family.items():
        if not isinstance(member, dict):
            raise ValueError(f'{path}: member {name!r} = {member!r} must be a mapping of vehicle fields')
        unknown = set(member) - set(PLANT_FIELDS)
        if unknown:
            raise ValueError(f'{path}: member {name!r} sets {sorted(unknown)}; a member may set only '
                             f'{", ".join(PLANT_FIELDS)}')
    return family


def plant_overrides(plant, family_path=None) -> dict:
    """The vehicle-field overrides of `plant`: a family member's name, a mapping, or None / '' (nothing)."""
    if not plant:
        return {}
    if isinstance(plant, dict):
        unknown = set(plant) - set(PLANT_FIELDS)
        if unknown:
            raise ValueError(f'plant sets {sorted(unknown)}; a plant may set only {", ".join(PLANT_FIELDS)}')
        return plant
    family = load_plant_family(family_path)
    if plant not in family:
        raise ValueError(f'plant = {plant!r} is not a member of the plant family ({", ".join(family)})')
    return family[plant]


def load_vehicle_fields(path, plant=None, family_path=None) -> tuple[dict, str]:
    """(vehicle_fields of the file with the plant's overrides applied, the name its errors go by)."""
    data = dict(load_yaml(path))
    overrides = plant_overrides(plant, family_path)
    data.update(overrides)
    where = f'{path} with plant {plant!r}' if overrides else str(path)
    return vehicle_fields(data, where), where
