"""`quadflight fly` orchestration: validate, write params, start the node graph, watch, stop, report.

The graph is the one sim.launch.py describes: trajectory_node, position_controller, sim_node
(lockstep, use_sim_time) and the recorder, each a separate process in its own process group,
in a ROS domain of their own (quad_common.domains.isolated_domain, localhost discovery).
"""

import dataclasses
import datetime
import json
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from quad_bringup import processes
from quad_bringup.recorder import DEFAULT_TOPICS, installed
from quad_bringup.report import Completion, write_report
from quad_common.domains import isolated_domain
from quad_common.paths import REPO_ROOT, resolve_config
from quad_common.yaml_io import load_yaml
from quad_control.position import CONTROLLERS
from quad_trajectory.timing import ALLOCATIONS as TIME_ALLOCATIONS

EXIT_COMPLETED, EXIT_FAILED, EXIT_REFUSED, EXIT_INTERRUPTED = 0, 1, 2, 130

# node name -> (module, params file under config/)
GRAPH = {  # in start order (see STARTED_WHEN)
    'trajectory_node': ('quad_trajectory.trajectory_node', 'config/trajectory.yaml'),
    'sim_node': ('quad_sim.sim_node', 'config/sim.yaml'),
    'position_controller': ('quad_control.position_controller_node', 'config/control.yaml'),
}
RECORDER = 'recorder'


class MissionRefused(ValueError):
    """The mission (or an option) is unusable; nothing was started."""


@dataclass
class FlightOptions:
    mission: Path
    controller: str | None = None         # None: the control profile's `controller`, else pd
    speed_mps: float | None = None
    time_allocation: str | None = None    # overrides the mission's trajectory.time_allocation (e.g. limits)
    out: Path | None = None
    vehicle: Path | None = None
    plant: str | None = None              # a plant family member for the simulated vehicle (config/plant_family.yaml)
    disturbances: str | None = None
    control_profile: Path | None = None   # a params file overriding config/control.yaml (e.g. control_fast.yaml)
    sim_parameters: dict | None = None    # sim_node parameters set last (sweep: seed, a plant-only vehicle file)
    rule: Completion | None = None        # None: the vehicle's completion rule (its YAML), with `completion` over it
    completion: dict = field(default_factory=dict)   # Completion field -> value given on the command line
    time_limit_factor: float = 3.0
    startup_timeout_s: float = 180.0      # wall clock until the first trajectory and odometry
    stall_timeout_s: float = 60.0         # wall clock without new odometry
    divergence_m: float = 1.0
    quiet: bool = False
    fly_anyway: bool = False              # fly a plan that fails the vehicle's feasibility check


@dataclass
class FlightResult:
    exit_code: int
    reason: str
    run_dir: Path | None = None
    metrics: dict | None = None
    pids: list = field(default_factory=list)


def validate(options: FlightOptions):
    """Loads and plans the mission with quad_trajectory (so a bad one is refused before anything starts).

    Returns the quad_trajectory Mission. Raises MissionRefused naming the problem.
    """
    from quad_trajectory import mission as mission_module

    if options.time_allocation is not None and options.time_allocation not in TIME_ALLOCATIONS:
        raise MissionRefused(f'--time-allocation {options.time_allocation!r} refused: must be one of '
                             f'{", ".join(TIME_ALLOCATIONS)}')
    if options.controller not in CONTROLLERS:
        raise MissionRefused(f'--controller {options.controller!r} refused: must be one of {", ".join(CONTROLLERS)}')
    if options.speed_mps is not None and not options.speed_mps > 0:
        raise MissionRefused(f'--speed {options.speed_mps} refused: must be > 0 m/s')
    path = Path(options.mission)
    if not path.is_file():
        raise MissionRefused(f'mission {path}: no such file')
    for name, value in (('--vehicle', options.vehicle), ('--control-profile', options.control_profile)):
        if value is not None and not Path(value).is_file():
            raise MissionRefused(f'{name} {value}: no such file')
    if options.plant:
        from quad_common.vehicle import load_plant_family
        try:
            family = load_plant_family()
        except (ValueError, OSError) as exc:
            raise MissionRefused(f'--plant {options.plant!r} refused: {exc}') from None
        if options.plant not in family:
            raise MissionRefused(f'--plant {options.plant!r} refused: must be one of {", ".join(family)}')
    try:
        mission = mission_module.load_mission(path)
        mission_module.plan_mission(mission, speed_mps=options.speed_mps, **plan_overrides(options))
    except (ValueError, KeyError, TypeError, OSError) as exc:
        raise MissionRefused(str(exc) if str(path) in str(exc) else f'{path}: {exc}') from None
    return mission


def flight_vehicle(options: FlightOptions, mission):
    """The vehicle the controller flies: --vehicle, else the mission's."""
    from quad_common.vehicle import load_vehicle

    return load_vehicle(options.vehicle) if options.vehicle is not None else mission.vehicle


def preflight_options(options: FlightOptions, mission, log=print) -> FlightOptions:
    """What the vehicle decides before anything starts: the completion rule (its YAML's `completion:` under the
    command line's values, unless a rule was given) and the plan's feasibility (quad_trajectory.feasibility),
    logged; an infeasible plan is refused (MissionRefused) unless fly_anyway, or replaced by the limits
    allocation when that fits and the mission asks for it (trajectory.if_infeasible: limits)."""
    from quad_trajectory.feasibility import preflight
    from quad_trajectory.mission import plan_mission

    vehicle = flight_vehicle(options, mission)
    if options.rule is None:
        options = dataclasses.replace(options, rule=Completion.for_vehicle(vehicle, **options.completion))
    if vehicle is None:
        return options
    report = preflight(mission, plan_mission(mission, speed_mps=options.speed_mps, **plan_overrides(options)),
                       vehicle, options.speed_mps)
    for line in report.lines():
        log(line)
    if report.ok or options.fly_anyway:
        return options
    if report.fits is not None and mission.if_infeasible == report.fits:
        log(f'flying time_allocation {report.fits}, as the mission asks (trajectory.if_infeasible)')
        return dataclasses.replace(options, time_allocation=report.fits)
    raise MissionRefused(f'the plan is not feasible on {vehicle.name} (above); --fly-anyway flies it all the same')


def plan_overrides(options: FlightOptions) -> dict:
    return {} if options.time_allocation is None else {'time_allocation': options.time_allocation}


DEFAULT_PROFILES = {'se3': 'config/control_se3.yaml'}  # a controller flown without --control-profile gets this


def with_profile_controller(options: FlightOptions) -> FlightOptions:
    """--controller if given, else the control profile's `controller`, else pd; a controller named without a
    profile flies its default profile (se3: the robust config/control_se3.yaml; pd and pid: the seed's gains)."""
    if options.controller is not None:
        if options.control_profile is None and options.controller in DEFAULT_PROFILES:
            return dataclasses.replace(options, control_profile=resolve_config(DEFAULT_PROFILES[options.controller]))
        return options
    controller = 'pd'
    if options.control_profile is not None and Path(options.control_profile).is_file():
        profile = load_yaml(options.control_profile) or {}
        controller = profile.get('position_controller', {}).get('ros__parameters', {}).get('controller', controller)
    return dataclasses.replace(options, controller=controller)


def write_flown_mission(options: FlightOptions, mission, path: Path) -> Path:
    """The mission file with this flight's trajectory overrides, its file paths made absolute (so the
    trajectory node plans exactly what was validated; kept in the run directory)."""
    data = load_yaml(options.mission)
    data['trajectory'] = {**(data.get('trajectory') or {}), **plan_overrides(options)}
    for key, value in (('vehicle', mission.vehicle_path), ('world', mission.world_path)):
        if value:
            data[key] = str(Path(value).resolve())
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def node_parameters(options: FlightOptions, mission) -> dict:
    """{node: {ros__parameters: ...}}: the config/ files plus what this flight sets."""
    params = {}
    for node, (_, config) in GRAPH.items():
        data = load_yaml(resolve_config(config)) or {}
        params[node] = dict(data.get(node, {}).get('ros__parameters', {}))
    if options.control_profile is not None:
        profile = load_yaml(options.control_profile) or {}
        params['position_controller'].update(profile.get('position_controller', {}).get('ros__parameters', {}))
    for node in params:
        params[node]['use_sim_time'] = True
    params['trajectory_node']['mission_file'] = str(Path(options.mission).resolve())
    if options.speed_mps is not None:
        params['trajectory_node']['speed_mps'] = float(options.speed_mps)
    params['position_controller'].update(controller=options.controller, lockstep=True, wait_for_trajectory=True)
    params['sim_node'].update(mode='lockstep', initial_position=[float(v) for v in mission.initial_position],
                              world=mission.world_path or '', robot_radius_m=float(mission.options.robot_radius_m))
    if options.vehicle is not None:
        vehicle = str(Path(options.vehicle).resolve())
        params['position_controller']['vehicle'] = vehicle
        params['sim_node']['vehicle'] = vehicle
    if options.disturbances is not None:
        params['sim_node']['disturbances'] = options.disturbances
    if options.plant:
        params['sim_node']['plant'] = options.plant
    params['sim_node'].update(options.sim_parameters or {})
    for p in params.values():  # files named in config/ are relative to the repository
        for key in ('vehicle', 'disturbances_file'):
            if p.get(key) and not Path(p[key]).is_absolute():
                p[key] = str(resolve_config(p[key]))
    return {node: {'ros__parameters': p} for node, p in params.items()}


def default_run_dir(mission_name: str, controller: str) -> Path:
    stamp = datetime.datetime.now().strftime('%Y%m%d-%H%M%S')
    return REPO_ROOT / 'runs' / f'{mission_name}-{controller}-{stamp}'


class _Interrupt:
    """SIGINT/SIGTERM to fly during a flight: remember it, stop in order (children are in their own groups)."""

    def __init__(self):
        self.signum = None
        self._old = {}

    def __enter__(self):
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._old[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum, frame):
        self.signum = signum

    def __exit__(self, *exc):
        for sig, old in self._old.items():
            signal.signal(sig, old)


def fly(options: FlightOptions, log=print) -> FlightResult:
    try:
        options = with_profile_controller(options)
        mission = validate(options)
        options = preflight_options(options, mission, log)
    except (MissionRefused, ValueError) as exc:
        return FlightResult(EXIT_REFUSED, str(exc))
    run_dir = Path(options.out) if options.out else default_run_dir(mission.name, options.controller)
    if (run_dir / 'bag').exists():
        return FlightResult(EXIT_REFUSED, f'--out {run_dir}: already holds a bag; choose a new run directory')
    try:
        params = node_parameters(options, mission)
    except (ValueError, OSError) as exc:
        return FlightResult(EXIT_REFUSED, f'parameters: {exc}')
    run_dir.mkdir(parents=True, exist_ok=True)
    if plan_overrides(options):
        flown = write_flown_mission(options, mission, run_dir / 'mission.yaml')
        params['trajectory_node']['ros__parameters']['mission_file'] = str(flown.resolve())
    params_file = run_dir / 'params.yaml'
    params_file.write_text(yaml.safe_dump(params, sort_keys=False))
    nodes = [processes.NodeProcess(name, module, ['--params-file', str(params_file)], run_dir / 'logs' / f'{name}.log')
             for name, (module, _) in GRAPH.items()]
    topics = ','.join(f'"{t}"' for t in DEFAULT_TOPICS)
    recorder = processes.NodeProcess(RECORDER, 'quad_bringup.recorder_node',
                                     ['-p', f'output_dir:={run_dir / "bag"}', '-p', f'topics:=[{topics}]'],
                                     run_dir / 'logs' / 'recorder.log')
    log(f'flying {options.mission} with {options.controller} -> {run_dir}')
    with isolated_domain() as (domain, env), _Interrupt() as interrupt:
        from quad_bringup.flight_monitor import FlightJudge, FlightMonitor

        judge = FlightJudge(options.rule, divergence_m=options.divergence_m,
                            time_limit_factor=options.time_limit_factor)
        monitor = FlightMonitor(domain, judge, recorder_name=RECORDER)
        try:
            recorder.start(env)  # first, so the latched plan and the first odometry are in the bag
            _write_pids(run_dir, [recorder])
            deadline = time.monotonic() + options.startup_timeout_s  # for every stage together
            reason = _await(_recorder_readers_missing, [recorder], monitor, interrupt, deadline, options)
            started = [recorder]
            for node in nodes:  # one at a time, each once what it publishes reaches the judge and the bag
                if reason is not None:
                    break
                node.start(env)
                started.append(node)
                _write_pids(run_dir, started)
                if node.name in STARTED_WHEN:
                    reason = _await(STARTED_WHEN[node.name], started, monitor, interrupt, deadline, options)
            if reason is None:
                reason = _watch(judge, monitor, started, interrupt, options, log)
        finally:
            stopped = processes.stop(nodes, log=log)
            stopped.update(processes.stop([recorder], log=log))
            monitor.close()
    pids = [p.pid for p in nodes + [recorder] if p.popen is not None]
    extra = {'mission': mission.name, 'controller': options.controller, 'speed_mps': options.speed_mps,
             'outcome': reason.reason}
    try:
        metrics = write_report(run_dir / 'bag', run_dir, extra, options.rule)
    except (ValueError, FileNotFoundError) as exc:
        return FlightResult(EXIT_FAILED if reason.ok else _failure_code(interrupt),
                            f'{reason.reason}; no report: {exc}', run_dir, None, pids)
    if interrupt.signum is not None:
        return FlightResult(EXIT_INTERRUPTED, reason.reason, run_dir, metrics, pids)
    if reason.ok and not (metrics['completed'] and not metrics['collided']):
        reason.ok, reason.reason = False, f'{reason.reason}, but the bag does not show completion'
    return FlightResult(EXIT_COMPLETED if reason.ok else EXIT_FAILED, reason.reason, run_dir, metrics, pids)


def _write_pids(run_dir: Path, started):
    (run_dir / 'pids.json').write_text(json.dumps({p.name: p.pid for p in started}) + '\n')


def _failure_code(interrupt):
    return EXIT_INTERRUPTED if interrupt.signum is not None else EXIT_FAILED


def _recorder_readers_missing(monitor) -> str | None:
    """The recorder must read every topic before any publisher starts: a flight of a few simulated seconds can
    be over in under a second of wall time, before a recorder still importing its libraries has subscribed."""
    missing = monitor.missing_readers(RECORDER, [t for t, spec in DEFAULT_TOPICS.items() if installed(spec)])
    return f'{RECORDER} not subscribed to {", ".join(missing)}' if missing else None


def _first_message_missing(topic: str, at_judge) -> Callable:
    """What a node must have delivered before the next one starts: its first `topic` message, to the judge and
    into the bag (the recorder reports its counts on diagnostics). A sample written while a reader is still being
    matched can wait for the writer's next heartbeat (Fast DDS: 3 s), and a lockstep flight of a few simulated
    seconds is over in less wall time than that, so fly waits for delivery instead of racing it."""
    def missing(monitor) -> str | None:
        waiting = [who for who, ok in (('the flight monitor', at_judge(monitor.judge)),
                                       (RECORDER, monitor.recorded.get(topic, 0) > 0)) if not ok]
        return f'no {topic} at {" and ".join(waiting)}' if waiting else None
    return missing


# The graph starts in GRAPH order; each node named here once its condition holds: the plan (latched, published
# once), then the simulator's odometry (it re-publishes t = 0 until a controller is up), then the controller.
STARTED_WHEN = {
    'trajectory_node': _first_message_missing('trajectory', lambda judge: judge.trajectory is not None),
    'sim_node': _first_message_missing('odom', lambda judge: judge.t_s is not None),
}


def _interrupted_or_dead(children, interrupt, when: str):
    """The Verdict for a signal to fly or a child that exited, else None (checked while starting and flying)."""
    from quad_bringup.flight_monitor import Verdict

    if interrupt.signum is not None:
        return Verdict(False, f'interrupted by {signal.Signals(interrupt.signum).name} {when}')
    for p in children:
        if (code := p.exit_code()) is not None:
            return Verdict(False, f'node {p.name} exited with status {code} ({p.log_path}):\n{p.log_tail()}')
    return None


def _await(missing, children, monitor, interrupt, deadline, options):
    """Spin the monitor until `missing(monitor)` is None (-> None), else the Verdict why the flight cannot start."""
    from quad_bringup.flight_monitor import Verdict

    while (what := missing(monitor)) is not None:
        if (ended := _interrupted_or_dead(children, interrupt, 'before the flight')) is not None:
            return ended
        if time.monotonic() > deadline:
            return Verdict(False, f'{what} within {options.startup_timeout_s:.0f} s of start')
        monitor.spin_once(0.05)
    return None


def _watch(judge, monitor, children, interrupt, options, log):
    """Spin the monitor until a verdict, a dead child, a stall or a signal (the judge already has the plan and
    odometry: the staged start waited for both)."""
    from quad_bringup.flight_monitor import Verdict

    last_progress = last_change = time.monotonic()
    last_t = None
    while True:
        monitor.spin_once(0.05)
        now = time.monotonic()
        if judge.verdict is not None:
            return judge.verdict
        if (ended := _interrupted_or_dead(children, interrupt, f'at {judge.progress().strip()}')) is not None:
            return ended
        if judge.t_s != last_t:
            last_t, last_change = judge.t_s, now
        elif now - last_change > options.stall_timeout_s:
            return Verdict(False, f'simulation stalled: no new odometry for {options.stall_timeout_s:.0f} s')
        if not options.quiet and now - last_progress >= 1.0:
            log(judge.progress())
            last_progress = now
