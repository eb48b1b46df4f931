"""A fleet flown through the ROS graph (`quadflight fleet FLEET.yaml --graph`): one sim_node stepping every vehicle
under one /clock, each vehicle's trajectory_node and position_controller under its namespace, the recorder as the
simulator's lockstep follower (nothing lost), then each vehicle's metrics from the bag.

Processes: sim_node, the vehicles' nodes and the recorder in one process (quad_bringup.running.node_host; the
default: one interpreter and one DDS participant for all of them, so odometry and setpoints go from writer to
reader inside the process, the lockstep loop serves every controller's tick in its own wait, and the recorder takes
each message without a copy to another process; at the simulator's stop it takes what is queued and closes the bag,
as fly's does) or one process per node, the recorder's too (hosted=False, as launch_ros starts them). Why the
recorder in the host: each write to a reader in another process woke that process's threads, ~30 us of the
writer's wall time on 2 cores, and on a shared machine the recorder's process took the core the lockstep needed.
Everything runs on simulated time; sim_node ends the run at duration_s (the latest planned end plus SETTLE_S),
drains the recorder and exits; then the rest is stopped (processes.stop: SIGINT, SIGTERM, SIGKILL).

Per vehicle the bag holds /NAME/odom, /NAME/cmd/attitude_thrust, /NAME/trajectory and /NAME/diagnostics (the
simulator's collision, vehicle_collision and failsafe events); report.load_flights reads every vehicle's part in one
read. The fleet's flown separation and its collisions are computed from the recorded odometry with the simulator's own
contact rule (quad_sim.vehicle_contact), beside the events the simulator reported.
"""

import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from quad_bringup.analysis.metrics import Completion, compute_metrics
from quad_bringup.analysis.report import load_flights, write_report
from quad_bringup.offline.fleet_loop import FleetRun
from quad_bringup.running import graph, processes
from quad_common import contract
from quad_common.domains import isolated_domain
from quad_common.ros.domain_probe import domain_occupants
from quad_sim.vehicle_contact import ContactRule
from quad_trajectory.fleet import FleetPlan, resolved_fleet

SETTLE_S = 3.0              # sim time flown after the latest planned end (the completion rule's settle window)
TRAJECTORY_START_S = 1.0    # trajectory_node's start_delay_s (config/trajectory.yaml): the plans start here
# what the report reads (report.load_flight); not control/reference: 100 Hz of it per vehicle would double each
# controller's publishing cost (a reliable write to a matched reader) for nothing the report uses
VEHICLE_TOPICS = (contract.ODOM, contract.SETPOINT, contract.TRAJECTORY, contract.DIAGNOSTICS)
LOCKSTEP_TIMEOUT_S = 3.0    # wall time sim_node waits for a setpoint (a loaded machine; graph.FLY_LOCKSTEP_TIMEOUT_S)


@dataclass
class GraphTiming:
    total_s: float = 0.0     # the whole run: processes started to stopped
    flight_s: float = 0.0    # sim_node's stepping: its first step (the plans in) to its exit
    follower_wait_ms: float = float('nan')   # sim_node's longest wait for the recorder while stepping
    processes: dict = field(default_factory=dict)   # name -> exit code
    cpu_s: dict = field(default_factory=dict)       # name -> CPU seconds (user + system) when the flight ended


def duration_s(plan: FleetPlan) -> float:
    """Sim time to fly: the latest vehicle's start delay and plan, after the plans' start, plus SETTLE_S."""
    return TRAJECTORY_START_S + max(d + p.trajectory.duration_s for d, p in zip(plan.delays_s, plan.plans)) + SETTLE_S


@dataclass
class GraphRun:
    """A fleet's graph, ready to start: its files written under out_dir, its processes (not started)."""
    plan: FleetPlan
    out_dir: Path
    recorder: processes.NodeProcess | None   # None: a node of the simulator's process (hosted)
    nodes: list                # the simulator's process first (node_host, or sim_node), then the vehicles'
    end_s: float               # sim time at which sim_node ends the run

    @property
    def bag(self) -> Path:
        return self.out_dir / 'bag'

    @property
    def processes(self) -> list:
        """Every process of the run: the recorder's (when it has one), then the nodes'."""
        return [p for p in [self.recorder, *self.nodes] if p is not None]

    def start(self, env):
        for p in self.processes:
            p.start(env)

    def await_end(self, deadline: float, expected_dead=()):
        """Until the simulator's process has ended the run (exit 0); RuntimeError naming a process that exits before
        it (except those in expected_dead), or the deadline (time.monotonic) passing."""
        sim = self.nodes[0]
        others = [p for p in self.processes if p is not sim and p not in expected_dead]
        while sim.exit_code() is None:
            dead = next((p for p in others if p.exit_code() is not None), None)
            if dead is not None:
                raise RuntimeError(f'{dead.name} exited ({dead.exit_code()}) before the flight ended: '
                                   f'{dead.log_tail(4)}')
            if time.monotonic() > deadline:
                raise RuntimeError(f'the flight did not end in time (logs in {self.out_dir / "logs"})')
            time.sleep(0.05)  # polling children's exits (no event to await for them but waitpid, one at a time)
        if sim.exit_code() != 0:
            raise RuntimeError(f'{sim.name} exited {sim.exit_code()}: {sim.log_tail(4)}')

    def stop(self, log=print) -> dict:
        """The vehicles' nodes and the simulator, then the recorder (its bag closed last): {name: exit code}."""
        codes = processes.stop(self.nodes, log=log)
        if self.recorder is not None:
            codes.update(processes.stop([self.recorder], log=log))
        return codes


def prepare(plan: FleetPlan, out_dir, *, speed_mps: float | None = None, hosted: bool = True,
            followers: tuple[str, ...] = ()) -> GraphRun:
    """Writes out_dir/fleet.yaml (the fleet as flown: quad_trajectory.fleet.resolved_fleet) and params.yaml (every
    node's parameters, fully qualified) and makes the processes. followers: lockstep followers beside the recorder
    (quad_common.ros.lockstep), e.g. a probe that holds the simulator at a sim time."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    fleet_file = out_dir / 'fleet.yaml'
    fleet_file.write_text(yaml.safe_dump(resolved_fleet(plan), sort_keys=False))
    end_s = duration_s(plan)
    specs = graph.fleet_sim_graph(fleet_file, speed_mps=speed_mps, sim={
        'lockstep_followers': ','.join((graph.RECORDER, *followers)), 'lockstep_timeout_s': LOCKSTEP_TIMEOUT_S,
        'duration_s': end_s})
    names = plan.fleet.names
    recorder = graph.NodeSpec(graph.RECORDER, ({
        'output_dir': str(out_dir / 'bag'),
        'topics': [contract.CLOCK] + [f'/{n}/{t}' for n in names for t in VEHICLE_TOPICS],
        'lockstep_ack_after': ','.join(f'/{n}/{contract.TRAJECTORY}' for n in names)},))
    specs.insert(1, recorder)   # after sim_node: node_host hosts it beside the simulator only
    params_file = out_dir / 'params.yaml'
    params_file.write_text(yaml.safe_dump(graph.params_file_content(specs), sort_keys=False))
    if hosted:
        return GraphRun(plan, out_dir, None, processes.node_processes(specs, params_file, out_dir / 'logs', True),
                        end_s)
    nodes = processes.node_processes([s for s in specs if s is not recorder], params_file, out_dir / 'logs', False)
    return GraphRun(plan, out_dir, processes.node_processes([recorder], params_file, out_dir / 'logs', False)[0],
                    nodes, end_s)


def fly_graph(plan: FleetPlan, out_dir, *, speed_mps: float | None = None, hosted: bool = True,
              rule: Completion | None = None, log=print, timeout_s: float = 600.0, reports: bool = False,
              figures: bool = False) -> tuple[FleetRun, GraphTiming]:
    """Flies a planned (separation-checked) fleet through the ROS graph; returns its FleetRun (metrics per
    vehicle from the bag, the flown separation and collisions) and the timing. reports: each vehicle's report
    (metrics.json, report.md; with figures: figures/ drawn when the caller calls the run's finish(), after it gave
    the verdict) under out_dir/vehicles/NAME. Raises RuntimeError naming
    the process when one exits before the simulator has finished, or timeout_s (wall) passes."""
    run = prepare(plan, out_dir, speed_mps=speed_mps, hosted=hosted)
    timing = GraphTiming()
    log(f'flying {plan.fleet.name} ({len(plan.fleet.names)} vehicles) through the ROS graph '
        f'({"one process for the simulator and the vehicles" if hosted else "one process per node"}) -> {run.out_dir}')
    with isolated_domain(probe=domain_occupants) as (_domain, env):
        start = time.monotonic()
        try:
            run.start(env)
            run.await_end(start + timeout_s)
            timing.cpu_s = {p.name: cpu_s(p.pid) for p in run.processes if p is not run.nodes[0]}
            timing.flight_s, timing.follower_wait_ms = _lockstep_summary(run.nodes[0].log_path,
                                                                         time.monotonic() - start)
        finally:
            timing.processes = run.stop(log=log)
            timing.total_s = time.monotonic() - start
    reports_dir = run.out_dir / 'vehicles' if reports else None
    return fleet_run(run.bag, plan, rule, reports_dir, figures), timing


def cpu_s(pid: int) -> float:
    """User + system CPU seconds of a running process (/proc/PID/stat utime, stime); nan once it is gone."""
    try:
        fields = open(f'/proc/{pid}/stat').read().rsplit(')', 1)[1].split()
    except OSError:
        return float('nan')
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def _lockstep_summary(log_path: Path, fallback_s: float) -> tuple[float, float]:
    """(sim_node's wall time from its first advanced step to its end, its longest wait for the followers in ms) as
    it logs them ('lockstep: stepped ... in X s', 'lockstep: longest wait for followers Y ms'); fallback_s and
    nan for what the log does not say."""
    stepping_s, wait_ms = fallback_s, float('nan')
    try:
        lines = log_path.read_text(errors='replace').splitlines()
    except OSError:
        return stepping_s, wait_ms
    for line in lines:
        try:
            if 'lockstep: stepped' in line:
                stepping_s = float(line.split(' in ')[1].split(' s')[0])
            elif 'lockstep: longest wait for followers' in line:
                wait_ms = float(line.split('longest wait for followers ')[1].split(' ms')[0])
        except (IndexError, ValueError):
            pass
    return stepping_s, wait_ms


def fleet_run(bag_dir, plan: FleetPlan, rule: Completion | None = None, reports_dir=None,
              figures: bool = False) -> FleetRun:
    """Each vehicle's metrics from the fleet's bag by `rule` (None: each vehicle's own completion rule, as fly
    scores), and its report under reports_dir/NAME when given (figures: by the returned run's finish()); the flown
    separation and collisions on a common time base (the first vehicle's odometry stamps: in lockstep every
    vehicle has one at each step)."""
    names = plan.fleet.names
    flights = load_flights(bag_dir, names)
    controllers = {v.name: graph.controller_and_profile(v.controller, v.profile_path)[0] for v in plan.fleet.vehicles}
    metrics = {}
    rules = {v.name: rule or Completion.for_vehicle(v.mission.vehicle) for v in plan.fleet.vehicles}
    for name, flight in flights.items():
        if reports_dir is None:
            metrics[name] = compute_metrics(flight, rules[name])
        else:
            extra = {'mission': f'{plan.fleet.name}/{name}', 'controller': controllers[name]}
            metrics[name] = write_report(bag_dir, Path(reports_dir) / name, extra, rules[name], figures=False,
                                         flight=flight)
    finish = None
    if reports_dir is not None and figures:   # drawn by the caller's finish(): the verdict does not wait for them
        jobs = ({Path(reports_dir) / name: flights[name] for name in names},
                {Path(reports_dir) / name: metrics[name] for name in names})

        def finish():
            draw_reports_figures(*jobs)
    t = flights[names[0]].odom_t
    positions = {n: np.column_stack([np.interp(t, f.odom_t, f.position[:, a]) for a in range(3)])
                 for n, f in flights.items()}
    radii = [v.radius_m for v in plan.fleet.vehicles]
    separation, collisions = flown_contacts(t, [positions[n] for n in names], names, radii)
    for name, m in metrics.items():
        m['collided'] = bool(m['collided']) or any(name in (a, b) for _, a, b, _ in collisions)
        m['vehicle_collisions'] = sum(name in (a, b) for _, a, b, _ in collisions)
    return FleetRun(names, metrics, [], collisions, t, separation, plan, {}, positions, controllers, finish)


def _draw_report_figures(job) -> list[str]:
    flight, report_dir = job
    from quad_bringup.analysis.report import draw_figures

    return [str(p) for p in draw_figures(flight, report_dir)]


def draw_reports_figures(flights: dict, metrics: dict):
    """Each report directory's figures (flights: report dir -> Flight), drawn on every core at once (the
    figures are most of a report's time: one vehicle after another made a fleet's user wait for all of them in
    turn), then linked from its report.md. Raises RuntimeError naming the report whose figures failed."""
    from quad_bringup.analysis.report import write_markdown
    from quad_bringup.pools.executors import LocalExecutor

    dirs = list(flights)
    if len(dirs) == 1:
        drawn = {0: _draw_report_figures((flights[dirs[0]], dirs[0]))}
    else:
        pool = LocalExecutor(min(len(dirs), os.cpu_count() or 1))
        try:
            drawn = dict(pool.map_unordered(_draw_report_figures, [(flights[d], d) for d in dirs]))
        finally:
            pool.close()
    for k, d in enumerate(dirs):
        if isinstance(drawn[k], BaseException):
            raise RuntimeError(f'{d}: figures not drawn: {drawn[k]}') from drawn[k]
        write_markdown(metrics[d], d, [Path(f) for f in drawn[k]])


def flown_contacts(t, positions, names, radii_m) -> tuple[np.ndarray, list]:
    """(the smallest pairwise distance at each sample, [(time_s, a, b, distance_m)] of each contact's start),
    by the simulator's contact rule (quad_sim.vehicle_contact.ContactRule) between samples."""
    if len(positions) < 2:
        return np.full(len(t), np.inf), []
    p = np.stack(positions, axis=1)            # (samples, vehicles, 3)
    rule = ContactRule(names, radii_m)
    separation = np.empty(len(t))
    separation[0] = float(np.min(np.linalg.norm(p[0, rule.pair_j] - p[0, rule.pair_i], axis=1)))
    for k in range(1, len(t)):
        separation[k] = rule.check(p[k - 1], p[k], t[k - 1], t[k] - t[k - 1])[0]
    return separation, rule.collisions


def default_out_dir(fleet_name: str) -> Path:
    return Path('runs') / f'{fleet_name}-graph-{time.strftime("%Y%m%d-%H%M%S")}-{os.getpid()}'
