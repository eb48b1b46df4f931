"""`quadflight fly` orchestration: validate, write params, start the node graph, watch, stop, report.

The graph is the one sim.launch.py starts (quad_bringup.graph.sim_graph): trajectory_node, sim_node and
position_controller (lockstep, use_sim_time), plus the recorder, each a separate process in its own process group,
in a ROS domain of their own (quad_common.domains.isolated_domain, localhost discovery).

Reliability (README, Reliability): the recorder and fly's monitor are the simulator's lockstep followers
(quad_common.lockstep), so the bag and the verdict hold every step; the bag is checked against the simulator's
own step count; every node dies with fly (processes, bind_to_parent); SIGINT, SIGTERM and SIGHUP stop the graph in
order, close the bag and write the report; a dead controller leaves the simulator running until its failsafe has
landed the vehicle (LANDING_TIMEOUT_S).

Start-up: all four processes start at once (their imports and DDS discovery overlap); the order that matters is
kept by the lockstep itself: the simulator does not leave step 0 until both followers have taken it, and the
recorder and monitor acknowledge nothing before they have the plan.
"""

import dataclasses
import datetime
import json
import os
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from quad_bringup import graph, processes
from quad_bringup.inputs import check_inputs
from quad_bringup.limits import refusal
from quad_bringup.recorder import DEFAULT_TOPICS
from quad_bringup.report import Completion, load_flight, record_summary, write_report
from quad_common import contract
from quad_common.domain_probe import foreign_nodes
from quad_common.domains import isolated_domain
from quad_common.params import parameters_of, params_content
from quad_common.paths import REPO_ROOT
from quad_common.yaml_io import load_yaml
from quad_control.position import CONTROLLERS
from quad_trajectory.timing import ALLOCATIONS as TIME_ALLOCATIONS

EXIT_COMPLETED, EXIT_FAILED, EXIT_REFUSED, EXIT_INTERRUPTED = 0, 1, 2, 130

RECORDER = 'recorder'
CONTROLLER_NODE = 'position_controller'
LOCKSTEP_TIMEOUT_S = 3.0          # wall time sim_node waits for a setpoint before it takes the controller as gone
LANDING_TIMEOUT_S = 60.0          # wall time fly waits for the failsafe's landing after the controller died
STARTUP_NOTE_S = 1.0              # a start-up that takes longer says what it waits for


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
    figures: bool = True


@dataclass
class FlightResult:
    exit_code: int
    reason: str
    run_dir: Path | None = None
    metrics: dict | None = None
    pids: list = field(default_factory=list)
    notes: list = field(default_factory=list)   # lines to print with the verdict (record shortfall, landing)
    finish: Callable | None = None              # draws the figures (after the verdict is printed)


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
    for key, value in OPTION_VALUES(options):
        if reason := refusal(key, value):
            raise MissionRefused(reason)
    path = Path(options.mission)
    if not path.is_file():
        raise MissionRefused(f'mission {path}: no such file')
    for name, value in (('--vehicle', options.vehicle), ('--control-profile', options.control_profile)):
        if value is not None and not Path(value).is_file():
            raise MissionRefused(f'{name} {value}: no such file')
    try:
        check_inputs(options)   # the control profile, the disturbance profile
    except ValueError as exc:
        raise MissionRefused(str(exc)) from None
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
    logged; an infeasible plan is refused (MissionRefused, naming fastest and its time) unless fly_anyway, or
    replaced by the allocation the mission asks for (trajectory.if_infeasible: fastest or limits) when it fits."""
    from quad_trajectory.mission import plan_mission, preflight

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
    chosen = report.alternative(mission.if_infeasible)
    if chosen is not None:
        log(f'flying time_allocation {chosen[0]} ({chosen[1]:.2f} s planned), as the mission asks '
            f'(trajectory.if_infeasible)')
        return dataclasses.replace(options, time_allocation=chosen[0])
    fastest = report.alternative('fastest')
    instead = (f'; --time-allocation fastest flies it in {fastest[1]:.2f} s within the limits' if fastest else '')
    raise MissionRefused(f'the plan is not feasible on {vehicle.name} (above){instead}; --fly-anyway flies it all '
                         f'the same')


DOMAIN_PROBE_S = 0.5   # a ROS domain whose lock is free but holds nodes (a real bridge) is passed over


def OPTION_VALUES(options: FlightOptions):  # noqa: N802 (a table)
    """(quad_bringup.limits key, value) of every numeric option."""
    return [('speed_mps', options.speed_mps), ('time_limit_factor', options.time_limit_factor),
            *((key, _completion_value(options, key)) for key in ('position_tolerance_m', 'speed_tolerance_mps',
                                                                  'settle_s')),
            ('divergence_m', options.divergence_m), ('startup_timeout_s', options.startup_timeout_s),
            ('stall_timeout_s', options.stall_timeout_s)]


def _completion_value(options: FlightOptions, key: str):
    """A completion option as given: the explicit rule's, else the command line's (None: the vehicle's)."""
    return getattr(options.rule, key) if options.rule is not None else options.completion.get(key)


def plan_overrides(options: FlightOptions) -> dict:
    return {} if options.time_allocation is None else {'time_allocation': options.time_allocation}


def with_profile_controller(options: FlightOptions) -> FlightOptions:
    """--controller if given, else the control profile's `controller`, else pd; a controller named without a
    profile flies its default profile (quad_bringup.graph.controller_and_profile)."""
    controller, profile = graph.controller_and_profile(options.controller, options.control_profile)
    return dataclasses.replace(options, controller=controller, control_profile=Path(profile) if profile else None)


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


FLY_ONLY = {'sim_node': ('lockstep_followers', 'lockstep_timeout_s')}  # what fly adds to the launch graph


def node_specs(options: FlightOptions) -> list:
    """The graph sim.launch.py starts (quad_bringup.graph.sim_graph, lockstep), plus what only fly has: the
    recorder and fly's monitor as the simulator's lockstep followers, a longer lockstep timeout (a loaded
    machine), and the sweep's or the command line's plant, disturbances and sim_node parameters."""
    sim = {'lockstep_followers': f'{RECORDER},{graph.MONITOR}', 'lockstep_timeout_s': LOCKSTEP_TIMEOUT_S}
    if options.disturbances is not None:
        sim['disturbances'] = options.disturbances
    if options.plant:
        sim['plant'] = options.plant
    sim.update(options.sim_parameters or {})
    return graph.sim_graph(options.mission, controller=options.controller, control_profile=options.control_profile,
                           vehicle=options.vehicle, speed_mps=options.speed_mps, extra={'sim_node': sim})


def node_parameters(options: FlightOptions, mission=None) -> dict:
    """{node: {ros__parameters: ...}}: what each node of node_specs ends up with (files named in config/ made
    absolute, so the run directory's params.yaml holds on its own)."""
    params = {}
    for spec in node_specs(options):
        params.update(params_content(spec.name, graph.absolute_config_paths(spec.merged_parameters())))
    return params


def default_run_dir(mission_name: str, controller: str) -> Path:
    stamp = datetime.datetime.now().strftime('%Y%m%d-%H%M%S-%f')[:-3]   # milliseconds
    return REPO_ROOT / 'runs' / f'{mission_name}-{controller}-{stamp}'


def make_run_dir(requested: Path | None, default: Path) -> Path:
    """Creates the run directory. The default name is made unique atomically (mkdir without exist_ok, a -2, -3...
    suffix on collision: two flies in the same millisecond get two directories); an explicit --out may exist but
    must not hold a bag. Raises MissionRefused (one line) for a path that cannot be created or written."""
    if requested is not None:
        run_dir = Path(requested)
        if (run_dir / 'bag').exists():
            raise MissionRefused(f'--out {run_dir}: already holds a bag; choose a new run directory')
        try:
            run_dir.mkdir(parents=True, exist_ok=True)
            _check_writable(run_dir)
        except OSError as exc:
            raise MissionRefused(f'--out {run_dir}: cannot create or write it ({exc.strerror or exc})') from None
        if (run_dir / 'bag').exists():
            raise MissionRefused(f'--out {run_dir}: already holds a bag; choose a new run directory')
        return run_dir
    try:
        default.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise MissionRefused(f'run directory {default.parent}: cannot create it ({exc.strerror or exc}); '
                             'give --out') from None
    for n in range(1, 1000):
        run_dir = default if n == 1 else default.with_name(f'{default.name}-{n}')
        try:
            run_dir.mkdir()
            return run_dir
        except FileExistsError:
            continue
        except OSError as exc:
            raise MissionRefused(f'run directory {run_dir}: cannot create it ({exc.strerror or exc}); '
                                 'give --out') from None
    raise MissionRefused(f'run directory {default}: 999 runs of that name already exist')


def _check_writable(path: Path):
    probe = path / f'.write-test-{os.getpid()}'
    probe.write_text('')
    probe.unlink()


class _Interrupt:
    """SIGINT/SIGTERM/SIGHUP to fly during a flight: remember it, stop in order (children are in their own
    groups; a closed terminal's SIGHUP is a stop like Ctrl-C: bag closed, report written)."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)

    def __init__(self):
        self.signum = None
        self._old = {}

    def __enter__(self):
        for sig in self.SIGNALS:
            self._old[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum, frame):
        self.signum = signum

    def __exit__(self, *exc):
        for sig, old in self._old.items():
            signal.signal(sig, old)


class _Clock:
    """Wall-clock marks of fly's phases (QUADFLIGHT_TIMING=1 prints them to stderr: where the time goes)."""

    def __init__(self):
        self.t0 = time.monotonic()
        self.marks = []
        self.enabled = bool(os.environ.get('QUADFLIGHT_TIMING'))

    def mark(self, what):
        self.marks.append((what, time.monotonic() - self.t0))
        if self.enabled:
            import sys
            print(f'[{self.marks[-1][1]:6.2f} s] {what}', file=sys.stderr, flush=True)


def fly(options: FlightOptions, log=print, defer_figures=False) -> FlightResult:
    """Flies the mission (module docstring). The figures are drawn before this returns unless defer_figures:
    then the caller prints the verdict first and calls result.finish() (-> an error line or None)."""
    result = _fly(options, log)
    if result.finish is not None and not defer_figures:
        problem = result.finish()
        result.finish = None
        if problem:
            result.notes.append(problem)
    return result


def _fly(options: FlightOptions, log) -> FlightResult:
    clock = _Clock()
    try:
        options = with_profile_controller(options)
        mission = validate(options)
        options = preflight_options(options, mission, log)
        params = node_parameters(options, mission)
        run_dir = make_run_dir(options.out, default_run_dir(mission.name, options.controller))
    except MissionRefused as exc:
        return FlightResult(EXIT_REFUSED, str(exc))
    except (ValueError, OSError) as exc:
        return FlightResult(EXIT_REFUSED, f'parameters: {exc}')
    clock.mark('validated, run directory made')
    if plan_overrides(options):
        flown = write_flown_mission(options, mission, run_dir / 'mission.yaml')
        parameters_of(params, 'trajectory_node')['mission_file'] = str(flown.resolve())
    params_file = run_dir / 'params.yaml'
    params_file.write_text(yaml.safe_dump(params, sort_keys=False))
    nodes = [processes.NodeProcess(name, graph.MODULES[name], ['--params-file', str(params_file)],
                                   run_dir / 'logs' / f'{name}.log') for name in params]
    topics = ','.join(f'"{t}"' for t in DEFAULT_TOPICS)
    recorder = processes.NodeProcess(RECORDER, 'quad_bringup.recorder_node',
                                     ['-p', f'output_dir:={run_dir / "bag"}', '-p', f'topics:=[{topics}]',
                                      '-p', 'lockstep_ack_after:=trajectory'],
                                     run_dir / 'logs' / 'recorder.log')
    log(f'flying {options.mission} with {options.controller} -> {run_dir}')
    started = []
    with isolated_domain(probe=lambda d: foreign_nodes(d, DOMAIN_PROBE_S)) as (domain, env), \
            _Interrupt() as interrupt:
        for node in [recorder, *nodes]:  # at once: imports and discovery overlap (module docstring)
            node.start(env)
            started.append(node)
        _write_pids(run_dir, started)
        clock.mark('processes started')
        figure_worker = _FigureWorker.start(env) if options.figures else None
        from quad_bringup.flight_monitor import FlightJudge, FlightMonitor

        judge = FlightJudge(options.rule, divergence_m=options.divergence_m,
                            time_limit_factor=options.time_limit_factor)
        monitor = FlightMonitor(domain, judge)
        clock.mark('flight monitor up')
        fault = None
        try:
            deadline = time.monotonic() + options.startup_timeout_s
            reason = _await(_flight_not_started, started, monitor, interrupt, deadline, options, log)
            clock.mark('flight started (plan and odometry at the monitor and in the bag)')
            if reason is None:
                reason = _watch(judge, monitor, started, interrupt, options, log)
                clock.mark('verdict')
            if not reason.ok and (dead := _dead(nodes, CONTROLLER_NODE)) is not None and interrupt.signum is None:
                fault = _await_landing(dead, judge, monitor, started, interrupt, log)
                clock.mark('failsafe landing awaited')
        finally:
            stopped = processes.stop(nodes, log=log, idle=monitor.spin_once)
            stopped.update(processes.stop([recorder], log=log, idle=monitor.spin_once))
            monitor.close()
            clock.mark('graph stopped')
    pids = [p.pid for p in nodes + [recorder] if p.popen is not None]
    extra = {'mission': mission.name, 'controller': options.controller, 'speed_mps': options.speed_mps,
             'outcome': reason.reason}
    if fault is not None:
        extra['fault'] = fault
    published = monitor.published.get('steps')
    try:
        flight = load_flight(run_dir / 'bag')
        metrics = write_report(run_dir / 'bag', run_dir, extra, options.rule, published_steps=published,
                               figures=False, flight=flight)
    except (ValueError, FileNotFoundError) as exc:
        if figure_worker:
            figure_worker.cancel()
        return FlightResult(EXIT_FAILED if reason.ok else _failure_code(interrupt),
                            f'{reason.reason}; no report: {exc}', run_dir, None, pids)
    clock.mark('metrics and report.md written')
    notes = [record_summary(metrics['record'])]
    if fault is not None:
        notes.append(fault['summary'])
    if judge.completed_at_s is not None and metrics['completed'] and \
            abs(judge.completed_at_s - metrics['time_actual_s']) > 1e-6:
        notes.append(f'WARNING: the monitor saw completion at t = {judge.completed_at_s:.3f} s, the bag at '
                     f'{metrics["time_actual_s"]:.3f} s')
    finish = (lambda: _finish_figures(figure_worker, flight, run_dir, metrics, clock)) if figure_worker else None
    if interrupt.signum is not None:
        return FlightResult(EXIT_INTERRUPTED, reason.reason, run_dir, metrics, pids, notes, finish)
    if reason.ok and not (metrics['completed'] and not metrics['collided']):
        reason.ok, reason.reason = False, f'{reason.reason}, but the bag does not show completion'
    if reason.ok and not metrics['record']['complete']:
        reason.ok, reason.reason = False, f'{reason.reason}, but the bag is incomplete'
    return FlightResult(EXIT_COMPLETED if reason.ok else EXIT_FAILED, reason.reason, run_dir, metrics, pids, notes,
                        finish)


class _FigureWorker:
    """A process started with the graph that imports matplotlib and the report while the flight runs, then
    draws the figures of the finished bag (quad_bringup.figure_worker): the verdict does not wait for them."""

    def __init__(self, popen):
        self.popen = popen

    @classmethod
    def start(cls, env):
        import subprocess
        import sys
        popen = subprocess.Popen([sys.executable, '-m', 'quad_bringup.figure_worker'], env=env, text=True,
                                 stdin=subprocess.PIPE, stdout=subprocess.PIPE, start_new_session=True)
        return cls(popen)

    def draw(self, flight, out_dir: Path) -> list[str]:
        """The figure paths written (relative to out_dir); raises RuntimeError with the worker's message."""
        import pickle
        import tempfile
        with tempfile.NamedTemporaryFile(suffix='.pickle') as f:
            pickle.dump(flight, f, protocol=pickle.HIGHEST_PROTOCOL)
            f.flush()
            out, _ = self.popen.communicate(json.dumps({'flight': f.name, 'out': str(out_dir)}) + '\n')
        answer = json.loads(out.strip().splitlines()[-1]) if out.strip() else {'error': 'no answer'}
        if 'error' in answer:
            raise RuntimeError(answer['error'])
        return answer['figures']

    def cancel(self):
        if self.popen.poll() is None:
            self.popen.kill()
            self.popen.wait()


def _finish_figures(worker: _FigureWorker, flight, run_dir: Path, metrics: dict, clock) -> str | None:
    """Figures into run_dir/figures and their links into report.md; an error line, or None."""
    from quad_bringup.report import write_markdown

    try:
        figures = worker.draw(flight, run_dir)
    except (RuntimeError, ValueError, OSError) as exc:
        return f'figures not drawn: {exc}'
    write_markdown(metrics, run_dir, [run_dir / f for f in figures])
    clock.mark('figures drawn')
    return None


def _write_pids(run_dir: Path, started):
    (run_dir / 'pids.json').write_text(json.dumps({p.name: p.pid for p in started}) + '\n')


def _failure_code(interrupt):
    return EXIT_INTERRUPTED if interrupt.signum is not None else EXIT_FAILED


def _dead(children, name):
    return next((p for p in children if p.name == name and p.exit_code() is not None), None)


def _flight_not_started(monitor) -> str | None:
    """What the flight still waits for before it is under way: the plan and odometry at the monitor and in the
    bag (the simulator holds step 0 until both followers have them; this only names the wait)."""
    judge = monitor.judge
    waiting = []
    if judge.trajectory is None:
        waiting.append('the plan at the flight monitor')
    if monitor.recorded.get('trajectory', 0) == 0:
        waiting.append('the plan in the bag')
    if judge.t_s is None:
        waiting.append('odometry from sim_node')
    if monitor.recorded.get('odom', 0) == 0:
        waiting.append('odometry in the bag')
    return ', '.join(waiting) if waiting else None


def _interrupted_or_dead(children, interrupt, when: str):
    """The Verdict for a signal to fly or a child that exited, else None (checked while starting and flying)."""
    from quad_bringup.flight_monitor import Verdict

    if interrupt.signum is not None:
        return Verdict(False, f'interrupted by {signal.Signals(interrupt.signum).name} {when}')
    for p in children:
        if (code := p.exit_code()) is not None:
            return Verdict(False, f'node {p.name} exited with status {code} ({p.log_path}):\n{p.log_tail()}')
    return None


def _await(missing, children, monitor, interrupt, deadline, options, log):
    """Spin the monitor until `missing(monitor)` is None (-> None), else the Verdict why the flight cannot start.
    After STARTUP_NOTE_S, and on each change, one line says what it still waits for."""
    from quad_bringup.flight_monitor import Verdict

    start = time.monotonic()
    said = None
    while (what := missing(monitor)) is not None:
        if (ended := _interrupted_or_dead(children, interrupt, 'before the flight')) is not None:
            return ended
        now = time.monotonic()
        if now > deadline:
            return Verdict(False, f'waiting for {what}: not there within {options.startup_timeout_s:.0f} s of start')
        if now - start > STARTUP_NOTE_S and what != said and not options.quiet:
            log(f'starting: waiting for {what} ({now - start:.1f} s; a first run compiles the simulator\'s '
                'kernels)')
            said = what
        monitor.spin_once(0.05)
    return None


def _watch(judge, monitor, children, interrupt, options, log):
    """Spin the monitor until a verdict, a dead child, a stall or a signal (the judge already has the plan and
    odometry: the start waited for both)."""
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


def _await_landing(dead, judge, monitor, children, interrupt, log) -> dict:
    """The controller died: the simulator runs on (after one lockstep timeout, 0.02 s per step) and its failsafe lands
    the vehicle. Spin until sim_node reports `disarmed`, another node dies, a signal or LANDING_TIMEOUT_S; the
    bag then shows the landing. Returns what died, when, and where the vehicle came down."""
    died_at = judge.t_s
    log(f'{dead.name} exited with status {dead.exit_code()} at t = {_since(judge, died_at)}: '
        'waiting for the simulator\'s failsafe to land the vehicle')
    others = [p for p in children if p is not dead]
    deadline = time.monotonic() + LANDING_TIMEOUT_S
    landed = None
    while time.monotonic() < deadline and interrupt.signum is None and not any(
            p.exit_code() is not None for p in others):
        monitor.spin_once(0.05)
        level, message, values = monitor.sim_events.get(contract.SIM_FAILSAFE, (None, '', {}))
        if 'disarmed' in message:
            landed = values
            break
    fault = {'node': dead.name, 'exit_code': dead.exit_code(), 'at_s': None if died_at is None else
             died_at - (judge.start_s or 0.0), 'landed': landed is not None}
    if landed is not None:
        # the failsafe status's time is its latest event's: here 'disarmed'
        fault['landed_at_s'] = contract.event_time_s(landed, contract.FAILSAFE_TIME_S) - (judge.start_s or 0.0)
        fault['landed_position_m'] = [float(landed[k]) for k in ('x', 'y', 'z')]
        where = ', '.join(f'{v:.2f}' for v in fault['landed_position_m'])
        fault['summary'] = (f'fault: {dead.name} died at t = {_since(judge, died_at)}; the failsafe landed the '
                            f'vehicle at t = {fault["landed_at_s"]:.2f} s at ({where}) m')
    else:
        fault['summary'] = (f'fault: {dead.name} died at t = {_since(judge, died_at)}; no landing reported by '
                            f'sim_node within {LANDING_TIMEOUT_S:.0f} s')
    return fault


def _since(judge, t_s) -> str:
    return '?' if t_s is None else f'{t_s - (judge.start_s or 0.0):.2f} s'
