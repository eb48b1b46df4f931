"""`quadflight fly`'s options and what is decided before anything starts: their checks (ranges: quad_bringup.limits;
files: quad_bringup.checks.inputs), the vehicle's preflight, the flown mission file, the graph's parameters
(quad_bringup.running.graph.fly_graph) and the run directory."""

import dataclasses
import datetime
import os
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from quad_bringup.analysis.completion import Completion
from quad_bringup.checks.inputs import check_inputs
from quad_bringup.limits import refusal
from quad_bringup.running import graph
from quad_common.paths import REPO_ROOT
from quad_common.yaml_io import load_yaml
from quad_trajectory.timing import ALLOCATIONS as TIME_ALLOCATIONS


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
    state_source: str | None = None       # position_controller's state_source over the profile's (external_pose:
                                          # the simulator's motion-capture stand-in, graph.FLY_MOCAP)
    rule: Completion | None = None        # None: the vehicle's completion rule (its YAML), with `completion` over it
    completion: dict = field(default_factory=dict)   # Completion field -> value given on the command line
    time_limit_factor: float = 3.0
    startup_timeout_s: float = 180.0      # wall clock until the first trajectory and odometry
    stall_timeout_s: float = 60.0         # wall clock without new odometry
    divergence_m: float = 1.0
    quiet: bool = False
    fly_anyway: bool = False              # fly a plan that fails the vehicle's feasibility check
    figures: bool = True
    process_per_node: bool = False        # each node its own process, as launch_ros starts them (else one node_host)


def validate(options: FlightOptions):
    """Loads and plans the mission with quad_trajectory (so a bad one is refused before anything starts).

    Returns the quad_trajectory Mission. Raises MissionRefused naming the problem (a bad --vehicle file: ValueError,
    as flight_vehicle raises it). The checks that need no numpy come first: option values, --out, files that are not
    there, a vehicle file's fields, a controller, disturbance profile or plant family member by name, the mission
    file's own values (pure Python rules that the later load applies too); such a refusal imports no controller and
    no planner.
    """
    if options.time_allocation is not None and options.time_allocation not in TIME_ALLOCATIONS:
        raise MissionRefused(f'--time-allocation {options.time_allocation!r} refused: must be one of '
                             f'{", ".join(TIME_ALLOCATIONS)}')
    for key, value in OPTION_VALUES(options):
        if reason := refusal(key, value):
            raise MissionRefused(reason)
    path = Path(options.mission)
    if not path.is_file():
        raise MissionRefused(f'mission {path}: no such file')
    if options.out is not None:
        refuse_out(Path(options.out))
    for name, value in (('--vehicle', options.vehicle), ('--control-profile', options.control_profile)):
        if value is not None and not Path(value).is_file():
            raise MissionRefused(f'{name} {value}: no such file')
    if options.vehicle is not None:   # its fields (pure Python): ValueError as flight_vehicle raises it later
        from quad_common.vehicle_file import load_vehicle_fields

        load_vehicle_fields(options.vehicle)
    from quad_control.controller_names import refusal as controller_refusal

    if (reason := controller_refusal(options.controller)) is not None:
        name = options.controller
        raise MissionRefused(reason.replace(f'controller = {name!r}', f'--controller {name!r}', 1))
    try:
        check_inputs(options)   # the control profile, the disturbance profile
    except ValueError as exc:
        raise MissionRefused(str(exc)) from None
    if options.plant:
        from quad_common.vehicle_file import load_plant_family
        try:
            family = load_plant_family()
        except (ValueError, OSError) as exc:
            raise MissionRefused(f'--plant {options.plant!r} refused: {exc}') from None
        if options.plant not in family:
            raise MissionRefused(f'--plant {options.plant!r} refused: must be one of {", ".join(family)}')
    from quad_trajectory.mission_file import mission_fields

    try:
        data = load_yaml(path)
        fields = mission_fields(data, os.fspath(path))   # the file's own values, refused before numpy is imported
        from quad_trajectory import mission as mission_module

        mission = mission_module.mission_from_dict(data, os.fspath(path), fields)
        mission_module.plan_mission(mission, speed_mps=options.speed_mps, **plan_overrides(options))
    except (ValueError, KeyError, TypeError, OSError) as exc:
        raise MissionRefused(str(exc) if str(path) in str(exc) else f'{path}: {exc}') from None
    check_controller(options, mission)
    return mission


def check_controller(options: FlightOptions, mission):
    """A user class is built (and probed on a hover) with the flight's vehicle here, so a class that cannot be built
    or gives no attitude / thrust setpoint is refused before anything starts (quad_control.plugins)."""
    from quad_control.controller_names import CONTROLLERS, ControllerRefused
    from quad_control.plugins import make_controller

    if options.controller in CONTROLLERS:
        return
    try:
        make_controller(options.controller, None, flight_vehicle(options, mission))
    except ControllerRefused as exc:
        name = options.controller
        raise MissionRefused(str(exc).replace(f'controller {name!r}', f'--controller {name!r}', 1)) from None


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
    profile flies its default profile (quad_bringup.running.graph.controller_and_profile)."""
    name = options.controller
    try:
        controller, profile = graph.controller_and_profile(name, options.control_profile)
    except ValueError as exc:   # the node's rule for `controller`, said as the option the user typed
        raise MissionRefused(str(exc).replace(f'controller = {name!r}', f'--controller {name!r}', 1)) from None
    return dataclasses.replace(options, controller=controller, control_profile=Path(profile) if profile else None)


def controller_note(options: FlightOptions) -> str | None:
    """A line when --controller differs from the control profile's own `controller` (pd flown with se3's gains):
    --controller wins, and says so."""
    if options.controller is None or options.control_profile is None:
        return None
    own = graph.profile_controller(options.control_profile)
    if own and own != options.controller:
        return (f'note: flying {options.controller} with the gains of {options.control_profile}, a profile for {own} '
                f'(its controller:); --controller wins: drop it to fly {own}')
    return None


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


def node_parameters(options: FlightOptions) -> dict:
    """The params file of fly's graph (graph.fly_graph): the flight's plant, disturbances and sim_node parameters
    over the launch graph's."""
    sim = {}
    if options.disturbances is not None:
        sim['disturbances'] = options.disturbances
    if options.plant:
        sim['plant'] = options.plant
    sim.update(options.sim_parameters or {})
    controller = {'state_source': options.state_source} if options.state_source else None
    return graph.params_file_content(graph.fly_graph(
        options.mission, controller=options.controller, control_profile=options.control_profile,
        vehicle=options.vehicle, speed_mps=options.speed_mps, sim=sim, controller_params=controller))


def default_run_dir(mission_name: str, controller: str) -> Path:
    controller = controller.rpartition(':')[2] or controller   # a user class: its name
    stamp = datetime.datetime.now().strftime('%Y%m%d-%H%M%S-%f')[:-3]   # milliseconds
    return REPO_ROOT / 'runs' / f'{mission_name}-{controller}-{stamp}'


# what fly writes into its run directory: an explicit --out holding any of them is refused (never overwritten)
RUN_OUTPUTS = ('bag', 'bag.repaired', 'metrics.json', 'report.md', 'figures', 'logs', 'params.yaml', 'pids.json',
               'mission.yaml')


def make_run_dir(requested: Path | None, default: Path) -> Path:
    """Creates the run directory. The default name is made unique atomically (mkdir without exist_ok, a -2, -3...
    suffix on collision: two flies in the same millisecond get two directories); an explicit --out may exist but
    must hold none of RUN_OUTPUTS (claim_run_dir checks again under the lock). Raises MissionRefused (one line) for
    a path that cannot be created or written."""
    if requested is not None:
        run_dir = Path(requested)
        refuse_out(run_dir)
        try:
            run_dir.mkdir(parents=True, exist_ok=True)
            _check_writable(run_dir)
        except OSError as exc:
            raise MissionRefused(f'--out {run_dir}: cannot create or write it ({exc.strerror or exc})') from None
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


def refuse_out(run_dir: Path):
    """An explicit --out that fly cannot use: a file, a directory another command writes now, or one holding any of
    RUN_OUTPUTS (MissionRefused). Checked before the mission is planned and again when the directory is made."""
    if run_dir.exists() and not run_dir.is_dir():
        raise MissionRefused(f'--out {run_dir}: a file, not a directory; choose a new run directory')
    from quad_bringup.checks.dir_lock import holder_of

    if (holder := holder_of(run_dir)) is not None:
        raise MissionRefused(_busy(run_dir, holder))
    _refuse_outputs(run_dir)


def claim_run_dir(run_dir: Path) -> int:
    """The run directory for this fly alone, before anything starts: its lock (quad_bringup.checks.dir_lock.claim_dir;
    the kernel drops it when fly ends, SIGKILL included), then none of RUN_OUTPUTS in it (so a second fly on one --out
    is refused, exit 2, naming the first, and nothing there is overwritten). Returns the lock's descriptor
    (os.close releases it); raises MissionRefused."""
    from quad_bringup.checks.dir_lock import DirectoryBusy, claim_dir

    try:
        fd = claim_dir(run_dir, 'fly')
    except DirectoryBusy as busy:
        raise MissionRefused(_busy(run_dir, busy)) from None
    except OSError as exc:
        raise MissionRefused(f'--out {run_dir}: cannot create or write it ({exc.strerror or exc})') from None
    try:
        _refuse_outputs(run_dir)
    except MissionRefused:
        os.close(fd)
        raise
    return fd


def _busy(run_dir: Path, holder) -> str:
    return f'--out {run_dir}: another command writes there now ({holder}); wait for it or choose another --out'


def _refuse_outputs(run_dir: Path):
    held = [name for name in RUN_OUTPUTS if os.path.lexists(run_dir / name)]
    if held:
        also = f' (and {", ".join(held[1:])})' if held[1:] else ''
        raise MissionRefused(f'--out {run_dir}: already holds {held[0]}{also}, which fly would write; it overwrites '
                             'nothing: choose a new run directory')


def _check_writable(path: Path):
    probe = path / f'.write-test-{os.getpid()}'
    probe.write_text('')
    probe.unlink()
