"""Fleet missions (docs/missions.md "Fleets"): named vehicles, each a single-vehicle mission of its own.

A fleet file has a `vehicles:` list. Each entry becomes the mission dict that `mission.mission_from_dict`
validates (its checks, its errors, with `vehicles[i] (name)` in front): the fleet's `vehicle`, `world`,
`robot_radius_m`, `yaw` and `trajectory` (merged key by key) are every vehicle's defaults; the waypoints are
the vehicle's own, or the fleet's shared `waypoints` shifted by its `offset` (a formation); a `start` is
prepended as the first waypoint (where the vehicle starts).

`plan_fleet` plans each vehicle with the planner, checks the pairwise separation over time
(quad_trajectory.separation) and, when the file asks for it, deconflicts by start delays or altitude layers
and checks again.
"""

import dataclasses
import os
from dataclasses import dataclass, field

import numpy as np

from quad_common import contract
from quad_common.yaml_io import load_yaml, refuse_number_text
from quad_trajectory import separation
from quad_trajectory.mission import Mission, mission_from_dict, plan_mission
from quad_trajectory.mission_kind import check_fleet_keys, is_fleet, is_fleet_file  # noqa: F401  (re-exported)

VEHICLE_KEYS = frozenset({'name', 'vehicle', 'start', 'waypoints', 'offset', 'yaw', 'trajectory', 'robot_radius_m',
                          'controller', 'profile', 'start_delay_s', 'autopilot', 'fcu_url', 'system_id'})
AUTOPILOTS = ('px4', 'ardupilot')   # a real vehicle's autopilot (quad_bridge's backends)
SYSTEM_ID_RANGE = (1, 255)          # a vehicle's MAVLink system id (PX4 MAV_SYS_ID, ArduPilot SYSID_THISMAV)
_FCU_SCHEMES = ('udpin:', 'udpout:', 'udp:', 'udpbcast:', 'tcp:', 'tcpin:')
_LISTENING = ('udpin:', 'udp:', 'tcpin:')   # the bridge binds the port: any two on one port collide
SEPARATION_KEYS = frozenset({'min_m', 'margin_m', 'deconflict', 'delay_step_s', 'max_delay_s', 'layer_m',
                             'max_layers'})
DECONFLICT = ('none', 'delays', 'altitude')
DEFAULT_RADIUS_M = 0.1       # a vehicle without robot_radius_m: the simulator's default robot radius
DEFAULT_MARGIN_M = 0.1       # tracking error and odometry noise on top of the two radii


@dataclass
class SeparationOptions:
    min_m: float | None = None          # None: r_i + r_j + margin_m per pair
    margin_m: float = DEFAULT_MARGIN_M
    deconflict: str = 'none'
    delay_step_s: float = 0.5
    max_delay_s: float = 30.0
    layer_m: float = 0.5
    max_layers: int = 4


@dataclass
class FleetVehicle:
    name: str
    mission: Mission
    radius_m: float                     # for separation and vehicle-vehicle collisions
    start_delay_s: float = 0.0
    controller: str | None = None       # None: the profile's, else pd
    profile_path: str | None = None     # a position_controller params file (config/control*.yaml)
    offset: np.ndarray | None = None
    autopilot: str | None = None        # real vehicles (the fleet bridge graph): px4 | ardupilot
    fcu_url: str | None = None          # its bridge's MAVLink address (mavlink_bridge fcu_url)
    system_id: int | None = None        # its MAVLink system id (the bridge's target_system)


@dataclass
class Fleet:
    path: str
    name: str
    vehicles: list
    separation: SeparationOptions = field(default_factory=SeparationOptions)
    data: dict = field(default_factory=dict, repr=False)   # the mapping it was read from

    @property
    def names(self) -> list:
        return [v.name for v in self.vehicles]


def _number(where, value, minimum=0.0, integer=False):
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and np.isfinite(value) and value >= minimum
    if not ok or (integer and value != int(value)):
        raise ValueError(f'{where} = {value!r} must be a finite {"whole " if integer else ""}number >= {minimum:g}')
    return int(value) if integer else float(value)


def _vector3(where, value):
    try:
        v = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        v = None
    if v is None or v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f'{where} = {value!r} must be [x, y, z] in metres')
    return v


def _separation(data, path) -> SeparationOptions:
    where = f'{path}: separation'
    if not isinstance(data, dict):
        raise ValueError(f'{where} = {data!r} must be a mapping')
    unknown = sorted(set(data) - SEPARATION_KEYS)
    if unknown:
        raise ValueError(f'{where}.{unknown[0]} is not a known key (known: {", ".join(sorted(SEPARATION_KEYS))})')
    refuse_number_text(data, sorted(SEPARATION_KEYS - {'deconflict'}), f'{where}.')
    o = SeparationOptions()
    values = {}
    for key in ('min_m', 'margin_m', 'max_delay_s'):
        if key in data:
            values[key] = _number(f'{where}.{key}', data[key])
    for key in ('delay_step_s', 'layer_m'):
        if key in data:
            values[key] = _number(f'{where}.{key}', data[key])
            if values[key] == 0:
                raise ValueError(f'{where}.{key} = {data[key]!r} must be > 0')
    if 'max_layers' in data:
        values['max_layers'] = _number(f'{where}.max_layers', data['max_layers'], 1, integer=True)
    if data.get('deconflict', o.deconflict) not in DECONFLICT:
        raise ValueError(f'{where}.deconflict = {data["deconflict"]!r} must be one of {", ".join(DECONFLICT)}')
    values['deconflict'] = data.get('deconflict', o.deconflict)
    return dataclasses.replace(o, **values)


def _autopilot(value):
    if value not in AUTOPILOTS:
        raise ValueError(f'autopilot = {value!r} must be one of {", ".join(AUTOPILOTS)}')
    return value


def _fcu_url(value):
    """The bridge's MAVLink address: udpin:/udpout:/udp:/udpbcast:/tcp:/tcpin:HOST:PORT or a serial device."""
    ok = isinstance(value, str) and (value.startswith('/dev/') or value.upper().startswith('COM'))
    if isinstance(value, str) and value.startswith(_FCU_SCHEMES):
        host, _, port = value.split(':', 1)[1].rpartition(':')
        ok = bool(host) and port.isdigit() and 0 < int(port) <= 65535
    if not ok:
        raise ValueError(f'fcu_url = {value!r} must be udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT (or udp:, '
                         'udpbcast:, tcpin:) or a serial device')
    return value


def fcu_endpoint(url: str):
    """What two bridges must not share: the port a listening URL binds (any host), else the address it talks to."""
    if url.startswith(_LISTENING):
        return ('listens on port', url.rpartition(':')[2])
    return ('talks to', url.split(':', 1)[1] if url.startswith(_FCU_SCHEMES) else url)


def _system_id(value):
    lo, hi = SYSTEM_ID_RANGE
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise ValueError(f'system_id = {value!r} must be a whole number {lo}..{hi} (the vehicle\'s MAVLink system '
                         'id: PX4 MAV_SYS_ID, ArduPilot SYSID_THISMAV)')
    return value


def _vehicle(entry, index, data, path, seen) -> FleetVehicle:
    name = entry.get('name') if isinstance(entry, dict) else None
    where = f'vehicles[{index}]' + (f' ({name})' if isinstance(name, str) else '')
    if not isinstance(entry, dict):
        raise ValueError(f'{path}: {where} = {entry!r} must be a mapping with a name')
    if not contract.is_vehicle_name(name):
        raise ValueError(f'{path}: {where}: name = {name!r} must be {contract.VEHICLE_NAME_RULE}')
    if name in seen:
        raise ValueError(f'{path}: {where}: name = {name!r} is already vehicles[{seen[name]}]\'s')
    seen[name] = index
    unknown = sorted(set(entry) - VEHICLE_KEYS)
    if unknown:
        raise ValueError(f'{path}: {where}: {unknown[0]} = {entry[unknown[0]]!r} is not a known key '
                         f'(known: {", ".join(sorted(VEHICLE_KEYS))})')
    try:
        refuse_number_text(entry, ('robot_radius_m', 'start_delay_s'), '')
        offset = None
        if 'waypoints' in entry and 'offset' in entry:
            raise ValueError(f'waypoints and offset = {entry["offset"]!r}: give one (own waypoints, or an offset on '
                             'the fleet\'s waypoints)')
        if 'waypoints' in entry:
            waypoints = entry['waypoints']
        elif 'waypoints' not in data:
            raise ValueError('waypoints is missing (and the fleet has no shared waypoints to offset)')
        else:
            offset = _vector3('offset', entry.get('offset', [0.0, 0.0, 0.0]))
            try:
                waypoints = (np.asarray(data['waypoints'], dtype=float) + offset).tolist()
            except (TypeError, ValueError):
                raise ValueError(f'the fleet\'s waypoints = {data["waypoints"]!r} must be a list of [x, y, z] in '
                                 'metres') from None
        if 'start' in entry:
            waypoints = [_vector3('start', entry['start']).tolist()] + list(waypoints)
        traj = data.get('trajectory') or {}
        own = entry.get('trajectory') or {}
        for what, value in (('trajectory', traj), ('trajectory', own)):
            if not isinstance(value, dict):
                raise ValueError(f'{what} = {value!r} must be a mapping')
        single = {k: data[k] for k in ('vehicle', 'world', 'robot_radius_m', 'yaw') if k in data}
        single.update({k: entry[k] for k in ('vehicle', 'robot_radius_m', 'yaw') if k in entry})
        single.update(name=name, waypoints=waypoints, trajectory={**traj, **own})
        if 'start' in entry and isinstance(single.get('yaw'), list) and single['yaw']:
            single['yaw'] = [single['yaw'][0]] + list(single['yaw'])   # the start faces the first waypoint's yaw
        delay = _number('start_delay_s', entry.get('start_delay_s', 0.0))
        controller = entry.get('controller')
        if controller is not None and not isinstance(controller, str):
            raise ValueError(f'controller = {controller!r} must be a controller name (pd, pid, se3, '
                             'package.module:Class)')
        profile = entry.get('profile')
        if profile is not None and (not isinstance(profile, str) or not profile):
            raise ValueError(f'profile = {profile!r} must be a control profile file (relative to the fleet file)')
        autopilot = entry.get('autopilot', data.get('autopilot'))
        autopilot = None if autopilot is None else _autopilot(autopilot)
        fcu_url = None if entry.get('fcu_url') is None else _fcu_url(entry['fcu_url'])
        system_id = None if entry.get('system_id') is None else _system_id(entry['system_id'])
    except ValueError as exc:
        raise ValueError(f'{path}: {where}: {exc}') from None
    try:
        mission = mission_from_dict(single, path)
    except ValueError as exc:   # the mission loader's error, with the vehicle named after the file
        text = str(exc)
        text = text[len(path) + 2:] if text.startswith(f'{path}: ') else text
        raise ValueError(f'{path}: {where}: {text}') from None
    radius = mission.options.robot_radius_m or DEFAULT_RADIUS_M
    profile_path = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(path)), profile)) if profile else None
    return FleetVehicle(name, mission, radius, delay, controller, profile_path, offset, autopilot, fcu_url, system_id)


def _refuse_shared_links(vehicles, path):
    """Two vehicles with one MAVLink system id, or two bridges on one port / address, are refused."""
    ids, endpoints = {}, {}
    for i, v in enumerate(vehicles):
        where = f'{path}: vehicles[{i}] ({v.name})'
        if v.system_id is not None:
            if v.system_id in ids:
                j = ids[v.system_id]
                raise ValueError(f'{where}: system_id = {v.system_id!r} is already vehicles[{j}] '
                                 f'({vehicles[j].name})\'s: every vehicle needs its own MAVLink system id')
            ids[v.system_id] = i
        if v.fcu_url is not None:
            endpoint = fcu_endpoint(v.fcu_url)
            if endpoint in endpoints:
                j = endpoints[endpoint]
                raise ValueError(f'{where}: fcu_url = {v.fcu_url!r} {endpoint[0]} {endpoint[1]} as vehicles[{j}] '
                                 f'({vehicles[j].name})\'s fcu_url = {vehicles[j].fcu_url!r} does: every bridge '
                                 'needs its own port')
            endpoints[endpoint] = i


def fleet_from_dict(data: dict, path: str = 'fleet') -> Fleet:
    """Validated Fleet; every error names the file, the vehicle (index and name), the field and the value."""
    check_fleet_keys(data, path)
    vehicles = data.get('vehicles')
    if not isinstance(vehicles, list) or not vehicles:
        raise ValueError(f'{path}: vehicles = {vehicles!r} must be a list of at least one vehicle')
    seen = {}
    if 'autopilot' in data:
        try:
            _autopilot(data['autopilot'])
        except ValueError as exc:
            raise ValueError(f'{path}: {exc}') from None
    fleet_vehicles = [_vehicle(entry, i, data, path, seen) for i, entry in enumerate(vehicles)]
    _refuse_shared_links(fleet_vehicles, path)
    options = _separation(data.get('separation') or {}, path)
    return Fleet(path, str(data.get('name', os.path.splitext(os.path.basename(path))[0])), fleet_vehicles, options,
                 dict(data))


def load_fleet(path) -> Fleet:
    path = os.fspath(path)
    return fleet_from_dict(load_yaml(path), path)


@dataclass
class FleetPlan:
    fleet: Fleet
    plans: list                   # planner.PlanResult per vehicle (after deconfliction)
    delays_s: list                # start delay per vehicle (after deconfliction)
    report: separation.SeparationReport
    changes: list = field(default_factory=list)   # what deconfliction changed, one line per vehicle
    before: separation.SeparationReport | None = None   # the check before deconfliction, when it ran

    @property
    def trajectories(self) -> list:
        return [p.trajectory for p in self.plans]

    def refusal(self) -> str | None:
        """One line naming the closest conflicting pair, the time and the distance; None when separated."""
        if self.report.ok:
            return None
        more = len(self.report.conflicts) - 1
        return f'{self.fleet.path}: separation conflict: {self.report.conflicts[0]}' + \
            (f' (and {more} more pair{"s" * (more > 1)})' if more else '')


def required(fleet: Fleet):
    return separation.required_matrix([v.radius_m for v in fleet.vehicles], fleet.separation.margin_m,
                                      fleet.separation.min_m)


def plan_fleet(fleet: Fleet, speed_mps: float | None = None, **overrides) -> FleetPlan:
    """Plans every vehicle (plan_mission), checks the separation, deconflicts when the file asks and re-checks."""
    plans = [plan_mission(v.mission, speed_mps=speed_mps, **overrides) for v in fleet.vehicles]
    delays = [v.start_delay_s for v in fleet.vehicles]
    req = required(fleet)
    names = fleet.names
    report = separation.check([p.trajectory for p in plans], names, delays, req)
    o = fleet.separation
    if report.ok or o.deconflict == 'none':
        return FleetPlan(fleet, plans, delays, report)
    layered = {}

    def candidates(k):
        v = fleet.vehicles[k]
        if o.deconflict == 'delays':
            for j in range(1, int(np.floor(o.max_delay_s / o.delay_step_s + 1e-9)) + 1):
                extra = j * o.delay_step_s
                yield plans[k].trajectory, delays[k] + extra, f'starts {extra:g} s later ({delays[k] + extra:g} s)'
        else:
            for j in range(1, o.max_layers + 1):
                for dz in (j * o.layer_m, -j * o.layer_m):
                    floor = v.mission.world.bounds[4] if v.mission.world is not None else 0.0
                    if np.min(v.mission.waypoints[:, 2]) + dz <= floor:
                        continue
                    shifted = dataclasses.replace(v.mission, waypoints=v.mission.waypoints + [0.0, 0.0, dz])
                    try:
                        result = plan_mission(shifted, speed_mps=speed_mps, **overrides)
                    except ValueError:      # e.g. the layer is outside the world
                        continue
                    layered[(k, dz)] = (shifted, result)
                    yield result.trajectory, delays[k], f'flies {dz:+g} m higher (altitude layer {dz:+g} m)'

    trajectories, new_delays, changes = separation.deconflict([p.trajectory for p in plans], names, delays, req,
                                                              candidates)
    for k, v in enumerate(fleet.vehicles):      # adopt the layer a vehicle was moved to: its mission and plan
        for (kk, _), (shifted, result) in layered.items():
            if kk == k and result.trajectory is trajectories[k]:
                fleet.vehicles[k] = dataclasses.replace(v, mission=shifted)
                plans[k] = result
    final = separation.check(trajectories, names, new_delays, req)
    return FleetPlan(fleet, plans, new_delays, final, changes, before=report)


def vehicle_mission(fleet: Fleet, name: str, speed_mps: float | None = None) -> tuple[Mission, float]:
    """One vehicle's mission and start delay as the fleet flies it (trajectory_node's `fleet_vehicle`): its own,
    or, where the file deconflicts, after plan_fleet's deconfliction (a later start, another altitude layer)."""
    if name not in fleet.names:
        raise ValueError(f'{fleet.path}: fleet_vehicle = {name!r} is not one of its vehicles '
                         f'({", ".join(fleet.names)})')
    k = fleet.names.index(name)
    if fleet.separation.deconflict == 'none':
        return fleet.vehicles[k].mission, fleet.vehicles[k].start_delay_s
    plan = plan_fleet(fleet, speed_mps=speed_mps)
    if not plan.report.ok:
        raise ValueError(plan.refusal())
    return plan.fleet.vehicles[k].mission, plan.delays_s[k]


def resolved_fleet(plan: FleetPlan) -> dict:
    """The fleet file as flown: every vehicle's waypoints (start, offset and altitude layer applied), yaw and
    start delay (after deconfliction) written out, its files absolute, deconfliction off. Each vehicle's part
    plans to the same trajectory as in `plan` (a trajectory_node with fleet_vehicle plans only its own)."""
    data = dict(plan.fleet.data)
    base = os.path.dirname(os.path.abspath(plan.fleet.path))

    def absolute(value):
        return os.path.normpath(os.path.join(base, value)) if isinstance(value, str) and value else value

    for key in ('vehicle', 'world'):
        if key in data:
            data[key] = absolute(data[key])
    data.pop('waypoints', None)
    if len(data['vehicles']) != len(plan.fleet.vehicles):
        raise ValueError(f'{plan.fleet.path}: the fleet\'s data holds {len(data["vehicles"])} vehicles, its plan '
                         f'{len(plan.fleet.vehicles)}')
    entries = []
    for raw, v, delay in zip(data['vehicles'], plan.fleet.vehicles, plan.delays_s):
        entry = {k: val for k, val in raw.items() if k not in ('start', 'offset', 'waypoints', 'yaw')}
        for key in ('vehicle', 'profile'):
            if key in entry:
                entry[key] = absolute(entry[key])
        entry['waypoints'] = v.mission.waypoints.tolist()
        yaw = v.mission.yaw
        if yaw is not None:
            entry['yaw'] = np.asarray(yaw, dtype=float).tolist()
        entry['start_delay_s'] = float(delay)
        entries.append(entry)
    data['vehicles'] = entries
    data['separation'] = {**(data.get('separation') or {}), 'deconflict': 'none'}
    data.pop('yaw', None)
    return data
