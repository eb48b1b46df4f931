"""One run of a sweep or a tune: its full parameters (a JSON mapping, hashed into the run's key), how it flies
(offline loop or the ROS graph) and the table row it yields. No rclpy at import.

A run's parameters hold everything that decides its result: the mission file (path relative to the repository
where possible, plus the SHA-256 of its text), speed and time allocation, every controller gain, the nominal
vehicle and the plant-only overrides, the disturbance profile as a mapping, the seed and the loop options. The
row adds the versions it was flown with, so `run_one(json.loads(row['params']))` flies it again.
"""

import functools
import hashlib
import importlib.metadata
import json
import platform
import subprocess
import tempfile
import time
from pathlib import Path

import yaml

from quad_common.paths import REPO_ROOT, resolve_config
from quad_common.yaml_io import load_yaml

MODES = ('offline', 'graph')
# controller profile keys a run carries (position_controller parameters that shape the control law)
GAIN_KEYS = ('controller', *(f'{g}_{a}' for g in ('kp', 'kd', 'ki') for a in 'xyz'), 'integral_limit_mps2',
             'use_feedforward', 'attitude_lead_s', 'disturbance_time_constant_s', 'thrust_scale',
             'drag_feedforward_per_s', 'drag_learning_time_s', 'velocity_from_position_s')
# the seed's Table 1/2 columns, the errors, and what a failure needs explained
METRIC_COLUMNS = ('time_planned_s', 'time_actual_s', 'length_planned_m', 'length_actual_m', 'avg_velocity_mps',
                  'rmse_m', 'max_error_m', 'waypoint_miss_max_m', 'final_error_m', 'time_over_s', 'max_speed_mps',
                  'max_tilt_deg', 'saturated_fraction', 'saturated_s', 'max_yaw_rate_radps', 'completed', 'collided')
LABEL_COLUMNS = ('key', 'mode', 'mission', 'speed_mps', 'controller_name', 'controller', 'vehicle_name',
                 'disturbance_name', 'wind_speed_mps', 'seed')
# a fleet mission's row (docs/quad_bringup.md "Many flights", fleet missions): empty for a single vehicle
FLEET_COLUMNS = ('fleet_size', 'vehicle_collisions', 'min_separation_m', 'planned_separation_m')
ROW_COLUMNS = LABEL_COLUMNS + METRIC_COLUMNS + FLEET_COLUMNS + ('failed', 'failure', 'wall_s', 'cpu_s', 'git_commit',
                                                                'versions', 'vehicles', 'params')
# how a fleet row's metric comes from its vehicles' (the rest: the worst vehicle, max)
FLEET_SUMS = ('length_planned_m', 'length_actual_m')
FLEET_MEANS = ('avg_velocity_mps',)


class SpecError(ValueError):
    """A sweep/tune spec entry is unusable; the message names the field and the value."""


def repo_relative(path) -> str:
    """A config path as the spec should store it: relative to the repository when inside it (portable to the
    workers of a cluster, each with its own checkout), else absolute."""
    try:
        p = resolve_config(path).resolve()
    except FileNotFoundError as exc:
        raise SpecError(str(exc)) from None
    try:
        return str(p.relative_to(REPO_ROOT))
    except ValueError:
        return str(p)


def file_sha(path) -> str:
    return hashlib.sha256(resolve_config(path).read_bytes()).hexdigest()[:16]


def run_key(params: dict) -> str:
    """The run's identity: a hash of its full parameters (resume skips keys already in the table)."""
    return hashlib.sha256(json.dumps(params, sort_keys=True, default=str).encode()).hexdigest()[:16]


# --- spec entries ---------------------------------------------------------------------------------------------

@functools.lru_cache(maxsize=1)
def default_gains() -> dict:
    """position_controller's parameter defaults overlaid with config/control.yaml: what `fly` starts from."""
    from quad_control.parameters import SPECS, profile_parameters

    values = {spec.name: spec.default for spec in SPECS if spec.name in GAIN_KEYS}
    node = profile_parameters(load_yaml(resolve_config('config/control.yaml')))
    values.update({k: v for k, v in node.items() if k in GAIN_KEYS})
    return values


def _param_specs() -> dict:
    from quad_control.parameters import SPECS

    return {spec.name: spec for spec in SPECS if spec.name in GAIN_KEYS}


def check_gain(name: str, value, where: str):
    """Raises SpecError unless `name` is a controller profile key and `value` passes its declared check."""
    from quad_common.params import check_value

    specs = _param_specs()
    if name not in specs:
        raise SpecError(f'{where}: unknown controller key {name!r}; known: {", ".join(GAIN_KEYS)}')
    spec = specs[name]
    kind = bool if isinstance(spec.default, bool) else str if isinstance(spec.default, str) else (int, float)
    if not isinstance(value, kind) or (kind is not bool and isinstance(value, bool)):
        raise SpecError(f'{where}: {name} = {value!r} refused: must be a {type(spec.default).__name__}')
    if (reason := check_value(spec, value)) is not None:
        raise SpecError(f'{where}: {reason}')


def controller_entry(entry, where: str) -> tuple[str, dict]:
    """(name, full gain set) of a spec's controller entry: `pd`, or {name, controller, profile, gains}."""
    if isinstance(entry, str):
        entry = {'controller': entry}
    if not isinstance(entry, dict):
        raise SpecError(f'{where} = {entry!r} must be a controller name or a mapping (name, controller, profile, '
                        'gains)')
    unknown = set(entry) - {'name', 'controller', 'profile', 'gains'}
    if unknown:
        raise SpecError(f'{where}: unknown key(s) {sorted(unknown)}; known: name, controller, profile, gains')
    values = dict(default_gains())
    if entry.get('profile'):
        from quad_control.parameters import profile_parameters

        node = profile_parameters(load_yaml(resolve_config(entry['profile'])))
        values.update({k: v for k, v in node.items() if k in GAIN_KEYS})
    gains = entry.get('gains') or {}
    if not isinstance(gains, dict):
        raise SpecError(f'{where}.gains = {gains!r} must be a mapping of controller keys')
    values.update(gains)
    if entry.get('controller'):
        values['controller'] = entry['controller']
    for key, value in values.items():
        check_gain(key, float(value) if isinstance(value, int) and not isinstance(value, bool) else value, where)
    values = {k: float(v) if isinstance(v, int) and not isinstance(v, bool) else v for k, v in values.items()}
    name = entry.get('name') or (Path(entry['profile']).stem if entry.get('profile') else values['controller'])
    return str(name), values


def vehicle_entry(entry, where: str) -> tuple[str, str | None, dict]:
    """(name, nominal vehicle file or None for the mission's, plant overrides) of a vehicle entry: a plant family
    member's name (config/plant_family.yaml), a vehicle file, or {name, file, plant: MEMBER | {fields}}. The
    overrides are stored resolved, so a run's key changes when its member is edited."""
    from quad_common.vehicle import load_vehicle
    from quad_common.vehicle_file import load_plant_family, plant_overrides
    from quad_trajectory.mission import DEFAULT_VEHICLE_PATH

    if isinstance(entry, str):
        entry = {'name': entry, 'plant': entry} if entry in load_plant_family() else {'file': entry}
    if entry is None:
        entry = {}
    if not isinstance(entry, dict):
        raise SpecError(f'{where} = {entry!r} must be a plant family member, a vehicle file or a mapping '
                        '(name, file, plant)')
    unknown = set(entry) - {'name', 'file', 'plant'}
    if unknown:
        raise SpecError(f'{where}: unknown key(s) {sorted(unknown)}; known: name, file, plant')
    file = repo_relative(entry['file']) if entry.get('file') else None
    plant = entry.get('plant') or {}
    if not isinstance(plant, (str, dict)):
        raise SpecError(f'{where}.plant = {plant!r} must be a plant family member or a mapping of plant fields')
    try:
        overrides = plant_overrides(plant)
        load_vehicle(resolve_config(file or DEFAULT_VEHICLE_PATH), plant=overrides)
    except ValueError as exc:
        raise SpecError(f'{where}.plant: {exc}') from None
    default = plant if isinstance(plant, str) else (Path(file).stem if file else 'mission') + ''.join(
        f' {k}={v}' for k, v in plant.items())
    return str(entry.get('name') or default), file, dict(overrides)


def disturbance_entry(entry, where: str) -> tuple[str, dict]:
    """(name, profile mapping) of a disturbance entry: a profile of config/disturbances.yaml, or
    {name, base: PROFILE, ...profile keys} (e.g. a wind speed on top of `drag`)."""
    from quad_bringup.offline.closed_loop import DISTURBANCES_FILE
    from quad_sim.disturbances import PROFILE_KEYS, profile_from_dict

    profiles = load_yaml(DISTURBANCES_FILE) or {}
    if isinstance(entry, str):
        entry = {'name': entry, 'base': entry}
    if not isinstance(entry, dict):
        raise SpecError(f'{where} = {entry!r} must be a profile name or a mapping (name, base, profile keys)')
    base = entry.get('base', 'none')
    if base != 'none' and base not in profiles:
        raise SpecError(f'{where}.base = {base!r}: no such profile in {DISTURBANCES_FILE}; known: '
                        f'{", ".join(sorted(profiles))}')
    profile = dict(profiles.get(base) or {})
    profile.update({k: v for k, v in entry.items() if k not in ('name', 'base')})
    try:
        profile_from_dict(profile, where)
    except ValueError as exc:
        raise SpecError(str(exc)) from None
    unknown = set(profile) - set(PROFILE_KEYS)
    if unknown:
        raise SpecError(f'{where}: unknown key(s) {sorted(unknown)}')
    return str(entry.get('name') or base), profile


def mission_entry(entry, where: str) -> dict:
    """{mission, mission_sha, speed_mps, time_allocation} of a mission entry: a file, or {file, speed_mps,
    time_allocation}; the mission is planned here so a bad one is refused before any run starts. A fleet mission
    (a file with `vehicles:`, quad_trajectory.fleet) adds `fleet: True`; its plan is checked here too, but a
    separation conflict is left to its runs (a failed row naming the pair)."""
    from quad_trajectory.fleet import is_fleet_file, load_fleet, plan_fleet
    from quad_trajectory.mission import load_mission, plan_mission

    if isinstance(entry, str):
        entry = {'file': entry}
    if not isinstance(entry, dict) or not entry.get('file'):
        raise SpecError(f'{where} = {entry!r} must be a mission file or a mapping with `file`')
    unknown = set(entry) - {'file', 'speed_mps', 'time_allocation'}
    if unknown:
        raise SpecError(f'{where}: unknown key(s) {sorted(unknown)}; known: file, speed_mps, time_allocation')
    speed = entry.get('speed_mps')
    if speed is not None and not (isinstance(speed, (int, float)) and speed > 0):
        raise SpecError(f'{where}.speed_mps = {speed!r} must be a number > 0')
    file = repo_relative(entry['file'])
    overrides = {'time_allocation': entry['time_allocation']} if entry.get('time_allocation') else {}
    fleet = is_fleet_file(resolve_config(file))
    try:
        if fleet:
            plan_fleet(load_fleet(resolve_config(file)), speed_mps=speed, **overrides)
        else:
            plan_mission(load_mission(resolve_config(file)), speed_mps=speed, **overrides)
    except (ValueError, KeyError, TypeError, OSError) as exc:
        raise SpecError(f'{where}: {exc}') from None
    return {'mission': file, 'mission_sha': file_sha(file), 'speed_mps': None if speed is None else float(speed),
            'time_allocation': entry.get('time_allocation'), **({'fleet': True} if fleet else {})}


def loop_defaults() -> dict:
    """A run's loop options when its spec sets none: the offline loop's (LoopOptions and its completion rule)."""
    from quad_bringup.offline.closed_loop import LoopOptions

    o = LoopOptions()
    return {'rate_hz': float(o.rate_hz), 'physics_rate_hz': float(o.physics_rate_hz),
            'time_limit_factor': float(o.time_limit_factor), 'position_tolerance_m': float(o.rule.position_tolerance_m),
            'speed_tolerance_mps': float(o.rule.speed_tolerance_mps)}


def loop_options(entry, where: str) -> dict:
    entry = entry or {}
    options = loop_defaults()
    if not isinstance(entry, dict) or set(entry) - set(options):
        raise SpecError(f'{where} = {entry!r} must be a mapping with keys from {", ".join(options)}')
    for key, value in entry.items():
        if not (isinstance(value, (int, float)) and not isinstance(value, bool) and value > 0):
            raise SpecError(f'{where}.{key} = {value!r} must be a number > 0')
        options[key] = float(value)
    return options


def seeds_entry(value, where: str) -> list[int]:
    """`seeds: 3` (0, 1, 2) or a list of integers."""
    if isinstance(value, int) and not isinstance(value, bool) and value > 0:
        return list(range(value))
    if isinstance(value, list) and value and all(isinstance(s, int) and not isinstance(s, bool) for s in value):
        return value
    raise SpecError(f'{where} = {value!r} must be a count > 0 or a list of integers')


def entries(spec: dict, key: str, parse, default):
    values = spec.get(key, default)
    if not isinstance(values, list) or not values:
        raise SpecError(f'{key} = {values!r} must be a non-empty list')
    return [parse(v, f'{key}[{i}]') for i, v in enumerate(values)]


def make_params(mission: dict, controller: tuple, vehicle: tuple, disturbance: tuple, seed: int, options: dict,
                mode: str) -> dict:
    return {**mission, 'controller_name': controller[0], 'gains': controller[1], 'vehicle_name': vehicle[0],
            'vehicle': vehicle[1], 'plant': vehicle[2], 'disturbance_name': disturbance[0],
            'disturbances': disturbance[1], 'seed': int(seed), 'options': options, 'mode': mode}


# --- flying one run -------------------------------------------------------------------------------------------

@functools.lru_cache(maxsize=1)
def versions() -> dict:
    """What the run was flown with (per worker process: a cluster's machines each report their own)."""
    from quad_bringup import __version__

    try:
        commit = subprocess.run(['git', '-C', str(REPO_ROOT), 'rev-parse', 'HEAD'], capture_output=True, text=True,
                                timeout=10).stdout.strip()
        dirty = subprocess.run(['git', '-C', str(REPO_ROOT), 'status', '--porcelain', '--untracked-files=no'],
                               capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        commit, dirty = '', ''
    packages = {}
    for name in ('numpy', 'scipy', 'numba', 'rclpy'):
        try:
            packages[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            pass
    return {'git_commit': commit + ('+dirty' if dirty else ''), 'quadflight': __version__,
            'python': platform.python_version(), **packages}


def loop_options_of(params: dict):
    from quad_bringup.analysis.report import Completion
    from quad_bringup.offline.closed_loop import LoopOptions
    from quad_control.parameters import gains_from

    o = params['options']
    gains = gains_from(params['gains'])
    plan = {'time_allocation': params['time_allocation']} if params.get('time_allocation') else None
    return LoopOptions(controller=params['gains']['controller'], gains=gains, speed_mps=params['speed_mps'],
                       plan_overrides=plan, disturbances=params['disturbances'], rate_hz=o['rate_hz'],
                       physics_rate_hz=o['physics_rate_hz'], time_limit_factor=o['time_limit_factor'],
                       rule=Completion(o['position_tolerance_m'], o['speed_tolerance_mps']),
                       vehicle_path=params['vehicle'], plant=params['plant'] or None, seed=params['seed'])


def _fly_graph(params: dict, out_dir: Path) -> tuple[dict | None, str | None]:
    """A full `fly` through the ROS graph (its own ROS domain); the profile, disturbance and plant files it needs
    are written into the run directory."""
    from quad_bringup.analysis.report import Completion
    from quad_bringup.running.flight import EXIT_INTERRUPTED, fly
    from quad_bringup.running.flight_options import FlightOptions
    from quad_common.vehicle import load_vehicle
    from quad_control.parameters import profile_content
    from quad_trajectory.mission import DEFAULT_VEHICLE_PATH, load_mission

    out_dir.mkdir(parents=True, exist_ok=True)
    profile = out_dir / 'control_profile.yaml'
    profile.write_text(yaml.safe_dump(profile_content(params['gains'])))
    disturbances = out_dir / 'disturbances.yaml'
    disturbances.write_text(yaml.safe_dump({params['disturbance_name']: params['disturbances']}))
    sim = {'seed': params['seed'], 'disturbances_file': str(disturbances.resolve()),
           'physics_rate_hz': params['options']['physics_rate_hz']}
    nominal = params['vehicle'] or load_mission(resolve_config(params['mission'])).vehicle_path or DEFAULT_VEHICLE_PATH
    if params['plant']:  # the plant-only fields into the simulator's vehicle file; the controller keeps nominal
        load_vehicle(resolve_config(nominal), plant=params['plant'])  # checked before anything starts
        data = {**load_yaml(resolve_config(nominal)), **params['plant']}
        plant = out_dir / 'plant_vehicle.yaml'
        plant.write_text(yaml.safe_dump(data))
        sim['vehicle'] = str(plant.resolve())
    o = params['options']
    result = fly(FlightOptions(
        mission=resolve_config(params['mission']), controller=params['gains']['controller'],
        speed_mps=params['speed_mps'], time_allocation=params.get('time_allocation'), out=out_dir / 'flight',
        vehicle=resolve_config(nominal), disturbances=params['disturbance_name'], control_profile=profile,
        sim_parameters=sim, rule=Completion(o['position_tolerance_m'], o['speed_tolerance_mps']),
        time_limit_factor=o['time_limit_factor'], quiet=True), log=lambda line: None)
    if result.exit_code == EXIT_INTERRUPTED:
        raise KeyboardInterrupt(result.reason)
    return result.metrics, None if result.exit_code == 0 else result.reason


def run_one(params: dict, graph_dir: str | None = None) -> dict:
    """Flies one run (offline loop, or the ROS graph when params['mode'] == 'graph') and returns its row.
    A run that raises is a failed row naming the error, never a lost one."""
    import numpy as np

    start, cpu = time.perf_counter(), time.process_time()
    metrics, failure, fleet = None, None, None
    try:
        if params.get('fleet'):
            if params['mode'] == 'graph':
                raise ValueError(GRAPH_FLEET_REFUSAL)
            metrics, failure, fleet = _fly_fleet(params)
        elif params['mode'] == 'graph':
            where = Path(graph_dir) if graph_dir else Path(tempfile.mkdtemp(prefix='quadflight-graph-'))
            metrics, failure = _fly_graph(params, where / run_key(params))
        else:
            from quad_bringup.offline.closed_loop import fly_offline

            metrics = fly_offline(resolve_config(params['mission']), loop_options_of(params))
            failure = metrics.get('stopped')
    except KeyboardInterrupt:
        raise
    except Exception as exc:  # noqa: BLE001 - a run's failure is data for the table
        failure = f'{type(exc).__name__}: {exc}'
    metrics = metrics or {}
    if failure is None and fleet is not None:
        failure = fleet.pop('failure')
    if failure is None and not (metrics.get('completed') and not metrics.get('collided')):
        failure = 'collided' if metrics.get('collided') else 'not completed within the time limit'
    v = versions()
    wind = np.asarray(params['disturbances'].get('wind_mps', [0.0, 0.0, 0.0]), dtype=float)
    row = {'key': run_key(params), 'mode': params['mode'], 'mission': Path(params['mission']).stem,
           'speed_mps': params['speed_mps'], 'controller_name': params['controller_name'],
           'controller': params['gains']['controller'], 'vehicle_name': params['vehicle_name'],
           'disturbance_name': params['disturbance_name'], 'wind_speed_mps': float(np.linalg.norm(wind)),
           'seed': params['seed']}
    for column in METRIC_COLUMNS:
        row[column] = _plain(metrics.get(column))
    row.update({c: (fleet or {}).get(c) for c in (*FLEET_COLUMNS, 'vehicles')})
    row.update(failed=failure is not None, failure=failure, wall_s=round(time.perf_counter() - start, 4),
               cpu_s=round(time.process_time() - cpu, 4),  # this process only (graph: not its nodes)
               git_commit=v['git_commit'], versions=v, params=params)
    return row


GRAPH_FLEET_REFUSAL = ('sweep --graph flies one-vehicle missions only; drop --graph to fly the fleet offline '
                       '(fleet_loop.fly_fleet), or fly it through the ROS graph alone with '
                       '`quadflight fleet FLEET.yaml --graph`')


def _plain(value):
    """A metric as JSON keeps it (numpy scalars to Python)."""
    import numpy as np

    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, (np.integer,)):
        return int(value)
    return float(value) if isinstance(value, (float, np.floating)) else value


def _fly_fleet(params: dict) -> tuple[dict, str | None, dict]:
    """A fleet mission flown offline (fleet_loop.fly_fleet) with the run's controller, gains, vehicle, plant,
    disturbance, seed and loop options on every vehicle (a vehicle naming its own controller or profile in the
    fleet file keeps it). Returns (the fleet's metrics, the simulator's stop reason or None, the fleet columns plus
    `vehicles` {name: that vehicle's metrics and controller} and `failure`: the separation conflict (the pair, the
    time, the distance), the vehicle-vehicle collisions or the vehicles that did not complete, None when all
    completed)."""
    import numpy as np

    from quad_bringup.offline.fleet_loop import fly_fleet
    from quad_trajectory.fleet import load_fleet, plan_fleet

    options = loop_options_of(params)
    fleet = load_fleet(resolve_config(params['mission']))
    plan = plan_fleet(fleet, speed_mps=options.speed_mps, **(options.plan_overrides or {}))
    closest = plan.report.closest
    columns = {'fleet_size': len(fleet.vehicles), 'planned_separation_m': None if closest is None else closest[2]}
    if plan.refusal():   # the file's own deconfliction (if any) left a conflict: refused as `fleet` refuses it
        return {}, None, {**columns, 'failure': 'separation conflict: ' + plan.refusal().split(
            'separation conflict: ', 1)[-1], 'vehicles': {v.name: {} for v in fleet.vehicles}}
    run = fly_fleet(fleet, options, fleet_plan=plan)
    per = run.metrics
    keep = (*METRIC_COLUMNS, 'vehicle_collisions', 'stopped')
    vehicles = {name: {'controller': run.controllers.get(name), 'start_delay_s': float(delay),
                       **{k: _plain(per[name].get(k)) for k in keep if k in per[name]}}
                for name, delay in zip(run.names, plan.delays_s)}
    metrics = {}
    for column in METRIC_COLUMNS:
        values = [m[column] for m in per.values() if m.get(column) is not None]
        if column == 'completed':
            metrics[column] = bool(values) and len(values) == len(per) and all(values)
        elif column == 'collided':
            metrics[column] = any(values) if values else None
        elif values:
            metrics[column] = float(sum(values) if column in FLEET_SUMS else
                                    sum(values) / len(values) if column in FLEET_MEANS else max(values))
    separation_m, separation_t = run.closest()
    columns.update(vehicle_collisions=len(run.collisions),
                   min_separation_m=separation_m if np.isfinite(separation_m) else None, vehicles=vehicles)
    stopped = [f'{n}: {m["stopped"]}' for n, m in per.items() if m.get('stopped')]
    failure = None
    if run.collisions:
        failure = 'vehicle collision: ' + '; '.join(f'{a} and {b} at t = {t:.2f} s ({d:.3f} m apart)'
                                                    for t, a, b, d in run.collisions[:3]) + \
            (f' (and {len(run.collisions) - 3} more)' if len(run.collisions) > 3 else '')
    elif any(m.get('collided') for m in per.values()):
        failure = 'collided: ' + ', '.join(n for n, m in per.items() if m.get('collided'))
    elif not metrics.get('completed'):
        failure = 'not completed within the time limit: ' + ', '.join(
            n for n, m in per.items() if not m.get('completed'))
    columns['failure'] = failure
    return metrics, '; '.join(stopped) or None, columns
