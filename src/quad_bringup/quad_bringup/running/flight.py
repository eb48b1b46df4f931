"""`quadflight fly`'s run: write params, start the node graph, watch, stop, report (its options and their checks:
quad_bringup.running.flight_options; the figures: quad_bringup.analysis.figure_worker).

The graph is the one sim.launch.py starts (quad_bringup.running.graph.fly_graph over sim_graph): trajectory_node,
sim_node and position_controller (lockstep, use_sim_time), plus the recorder, in a ROS domain of their own
(quad_common.domains.isolated_domain, localhost discovery). The three nodes and the recorder run in one node_host
process (one interpreter and one DDS participant to start, the lockstep's messages kept inside the process; the
recorder takes what the simulator published and closes the bag at its stop); with process_per_node each node,
the recorder too, is a process of its own, as launch_ros starts them (a controller that dies then leaves the
simulator's failsafe to land the vehicle). Each process has its own group.

Reliability (README, Reliability): the recorder and fly's monitor are the simulator's lockstep followers
(quad_common.ros.lockstep), so the bag and the verdict hold every step; the bag is checked against the simulator's
own step count; every node dies with fly (processes, bind_to_parent); SIGINT, SIGTERM and SIGHUP stop the graph in
order, close the bag and write the report; a dead controller leaves the simulator running until its failsafe has
landed the vehicle (LANDING_TIMEOUT_S).

Start-up: all processes start at once (their imports and DDS discovery overlap); the order that matters is
kept by the lockstep itself: the simulator does not leave step 0 until both followers have taken it, and the
recorder and monitor acknowledge nothing before they have the plan. The figures' process starts once the flight
is under way.
"""

import json
import os
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from quad_bringup.analysis.figure_worker import FigureWorker, finish_figures
from quad_bringup.running import graph, processes
from quad_bringup.running.flight_options import (
    FlightOptions,
    MissionRefused,
    claim_run_dir,
    controller_note,
    default_run_dir,
    make_run_dir,
    node_parameters,
    plan_overrides,
    preflight_options,
    validate,
    with_profile_controller,
    write_flown_mission,
)
from quad_common import contract
from quad_common.domains import isolated_domain
from quad_common.params import parameters_of

EXIT_COMPLETED, EXIT_FAILED, EXIT_REFUSED, EXIT_INTERRUPTED = 0, 1, 2, 130

LANDING_TIMEOUT_S = 60.0          # wall time fly waits for the failsafe's landing after the controller died
STARTUP_NOTE_S = 1.0              # a start-up that takes longer says what it waits for


@dataclass
class FlightResult:
    exit_code: int
    reason: str
    run_dir: Path | None = None
    metrics: dict | None = None
    pids: list = field(default_factory=list)
    notes: list = field(default_factory=list)   # lines to print with the verdict (record shortfall, landing)
    finish: Callable | None = None              # draws the figures (after the verdict is printed)
    release: Callable | None = None             # gives up the run directory's lock (after the figures)


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
    release, result.release = result.release or (lambda: None), None
    if result.finish is None:
        release()
    elif not defer_figures:
        try:
            problem = result.finish()
        finally:
            release()
        result.finish = None
        if problem:
            result.notes.append(problem)
    else:
        draw = result.finish

        def finish():
            try:
                return draw()
            finally:
                release()
        result.finish = finish
    return result


def _fly(options: FlightOptions, log) -> FlightResult:
    clock = _Clock()
    try:
        note = controller_note(options)
        options = with_profile_controller(options)
        mission = validate(options)
        if note:
            log(note)
        options = preflight_options(options, mission, log)
        params = node_parameters(options)
        run_dir = make_run_dir(options.out, default_run_dir(mission.name, options.controller))
        lock = claim_run_dir(run_dir)
    except MissionRefused as exc:
        return FlightResult(EXIT_REFUSED, str(exc))
    except (ValueError, OSError) as exc:
        return FlightResult(EXIT_REFUSED, f'parameters: {exc}')
    try:
        result = _fly_in(run_dir, options, mission, params, clock, log)
    except BaseException:
        os.close(lock)
        raise
    result.release = lambda: os.close(lock)
    return result


def _fly_in(run_dir: Path, options: FlightOptions, mission, params: dict, clock, log) -> FlightResult:
    """_fly once the run directory is this fly's."""
    # here, not at the top: a refusal before start-up does not wait for numpy, rosbags and the recorder's imports
    from quad_bringup.recording.recorder import DEFAULT_TOPICS

    clock.mark('validated, run directory made')
    if plan_overrides(options):
        flown = write_flown_mission(options, mission, run_dir / 'mission.yaml')
        parameters_of(params, 'trajectory_node')['mission_file'] = str(flown.resolve())
    params = {graph.RECORDER: {'ros__parameters': {'output_dir': str(run_dir / 'bag'), 'topics': list(DEFAULT_TOPICS),
                                                  'lockstep_ack_after': 'trajectory'}}, **params}
    params_file = run_dir / 'params.yaml'
    params_file.write_text(yaml.safe_dump(params, sort_keys=False))
    specs = [graph.NodeSpec(name) for name in params]
    if options.process_per_node:   # the recorder a process of its own too, stopped after the nodes (its drain)
        nodes = processes.node_processes([s for s in specs if s.name != graph.RECORDER], params_file,
                                         run_dir / 'logs', hosted=False)
        recorders = processes.node_processes([s for s in specs if s.name == graph.RECORDER], params_file,
                                             run_dir / 'logs', hosted=False)
    else:   # one process: the recorder drains and closes the bag after the simulator's loop (node_host)
        nodes = processes.node_processes(specs, params_file, run_dir / 'logs', hosted=True)
        recorders = []
    log(f'flying {options.mission} with {options.controller} -> {run_dir}')
    # the figures' process now, before the monitor's DDS threads: forked from this one (figure_worker)
    figure_worker = FigureWorker.prepare() if options.figures else None
    try:
        return _fly_graph(run_dir, options, mission, nodes, recorders, figure_worker, clock, log)
    except BaseException:
        if figure_worker:
            figure_worker.cancel()
        raise


def _fly_graph(run_dir, options, mission, nodes, recorders, figure_worker, clock, log) -> FlightResult:
    """_fly_in from the processes' start to the report (figure_worker: FigureWorker.prepare's, or None)."""
    from quad_bringup.analysis.report import load_flight, record_summary, write_report
    from quad_common.ros.domain_probe import domain_occupants
    from quad_control.parameters import NODE_NAME as CONTROLLER_NODE

    started = []
    with isolated_domain(probe=domain_occupants) as (domain, env), \
            _Interrupt() as interrupt:
        for node in [*recorders, *nodes]:  # at once: imports and discovery overlap (module docstring)
            node.start(env)
            started.append(node)
        _write_pids(run_dir, started)
        forked = ', '.join(p.name for p in started if isinstance(p.popen, processes.ForkedProcess))
        clock.mark('processes started' + (f' (forked: {forked})' if forked else ''))
        from quad_bringup.running.flight_monitor import FlightJudge, FlightMonitor

        judge = FlightJudge(options.rule, divergence_m=options.divergence_m,
                            time_limit_factor=options.time_limit_factor)
        monitor = FlightMonitor(domain, judge)
        clock.mark('flight monitor up')
        fault = None
        try:
            deadline = time.monotonic() + options.startup_timeout_s
            reason = _await(_flight_not_started, started, monitor, interrupt, deadline, options, log)
            clock.mark('flight started (plan and odometry at the monitor and in the bag)')
            # the figures' process now: its imports (matplotlib, ~0.6 s of CPU) overlap the flight, which waits on
            # the lockstep more than it computes, not the start-up, where every process computes at once
            if figure_worker:
                figure_worker.begin(env)
                clock.mark('figure worker importing')
            if reason is None:
                reason = _watch(judge, monitor, started, interrupt, options, log)
                clock.mark('verdict')
            if not reason.ok and (dead := _dead(nodes, CONTROLLER_NODE)) is not None and interrupt.signum is None:
                fault = _await_landing(dead, judge, monitor, started, interrupt, log)
                clock.mark('failsafe landing awaited')
        finally:
            stopped = processes.stop(nodes, log=log, idle=monitor.spin_once)
            clock.mark('nodes stopped')
            stopped.update(processes.stop(recorders, log=log, idle=monitor.spin_once))
            monitor.close()
            clock.mark('graph stopped')
    pids = [p.pid for p in nodes + recorders if p.popen is not None]
    extra = {'mission': mission.name, 'controller': options.controller, 'speed_mps': options.speed_mps,
             'outcome': reason.reason}
    if fault is not None:
        extra['fault'] = fault
    published = (monitor.published_stamp_ns, monitor.published['steps']) if 'steps' in monitor.published else None
    try:
        flight = load_flight(run_dir / 'bag')
        metrics = write_report(run_dir / 'bag', run_dir, extra, options.rule, published=published,
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
    finish = (lambda: finish_figures(figure_worker, flight, run_dir, metrics, clock.mark)) if figure_worker else None
    if interrupt.signum is not None:
        return FlightResult(EXIT_INTERRUPTED, reason.reason, run_dir, metrics, pids, notes, finish)
    if reason.ok and not (metrics['completed'] and not metrics['collided']):
        reason.ok, reason.reason = False, f'{reason.reason}, but the bag does not show completion'
    if reason.ok and not metrics['record']['complete']:
        reason.ok, reason.reason = False, f'{reason.reason}, but the bag is incomplete'
    return FlightResult(EXIT_COMPLETED if reason.ok else EXIT_FAILED, reason.reason, run_dir, metrics, pids, notes,
                        finish)


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
    from quad_bringup.running.flight_monitor import Verdict

    if interrupt.signum is not None:
        return Verdict(False, f'interrupted by {signal.Signals(interrupt.signum).name} {when}')
    for p in children:
        if (code := p.exit_code()) is not None:
            return Verdict(False, f'node {p.name} exited with status {code} ({p.log_path}):\n{p.log_tail()}')
    return None


def _await(missing, children, monitor, interrupt, deadline, options, log):
    """Spin the monitor until `missing(monitor)` is None (-> None), else the Verdict why the flight cannot start.
    After STARTUP_NOTE_S, and on each change, one line says what it still waits for."""
    from quad_bringup.running.flight_monitor import Verdict

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
    from quad_bringup.running.flight_monitor import Verdict

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
