"""The node graphs, described once (no launch, no rclpy): which nodes, with which parameters, in start order.

`quadflight fly` starts the simulated graph from `sim_graph`; launch/sim.launch.py, px4.launch.py and
ardupilot.launch.py turn the same NodeSpecs into launch_ros Nodes (`launch_node`). A NodeSpec's parameters are
what launch_ros passes: params files and dicts, in order, the later one winning (launch_ros writes a dict to a
file under the '/**' key and gives every entry as `--params-file`); `merged_parameters` is what the node ends
up with, `ros_arguments` the command line launch_ros gives its console script.
"""

import dataclasses
import re
from pathlib import Path

import yaml

from quad_common.params import parameters_of, params_content
from quad_common.paths import resolve_config
from quad_common.yaml_io import load_yaml

# executable (console script of the package's setup.py) -> the module it runs (`python -m`, fly's processes)
MODULES = {
    'trajectory_node': 'quad_trajectory.trajectory_node',
    'position_controller': 'quad_control.position_controller_node',
    'sim_node': 'quad_sim.sim_node',
    'mavlink_bridge': 'quad_bridge.mavlink_bridge_node',
    'recorder': 'quad_bringup.recording.recorder_node',
}
PACKAGES = {'trajectory_node': 'quad_trajectory', 'position_controller': 'quad_control', 'sim_node': 'quad_sim',
            'mavlink_bridge': 'quad_bridge', 'recorder': 'quad_bringup'}
CONFIG_FILES = {'trajectory_node': 'trajectory.yaml', 'position_controller': 'control.yaml', 'sim_node': 'sim.yaml',
                'mavlink_bridge': 'bridge_{autopilot}.yaml'}
# a controller flown without a control profile gets this one (pd and pid: the seed's gains in control.yaml)
DEFAULT_PROFILES = {'se3': 'control_se3.yaml'}
REAL_VEHICLE_PROFILE = 'control_real.yaml'       # the bridge graphs' default
REAL_VEHICLE = 'vehicles/px4_quad.yaml'
AUTOPILOTS = ('px4', 'ardupilot')
# the bridge graphs' motion capture (docs/bridge.md "Indoor flight"): off, or the frame of external/pose, which the
# bridge forwards to the autopilot's estimator (external_pose_enabled, external_pose_frame)
EXTERNAL_POSE_OFF = 'off'
SIM_MODES = ('lockstep', 'realtime')
CONFIG_PATH_PARAMETERS = ('vehicle', 'disturbances_file')
MONITOR = 'fly_monitor'   # fly's flight monitor node (quad_bringup.running.flight_monitor), a lockstep follower
RECORDER = 'recorder'     # fly's bag writer (quad_bringup.recording.recorder_node), the other lockstep follower
FLY_LOCKSTEP_TIMEOUT_S = 3.0   # fly's sim_node waits this long (wall time) for a setpoint: a loaded machine
# the simulator's motion-capture stand-in (quad_sim.mocap) when fly's controller flies from it: a frame per 10 ms
# lockstep step (the control rate), 1 mm and 2 mrad RMS, delivered at once (in lockstep a tick waits for the frame
# stamped at it: a latency would hold the lockstep)
FLY_MOCAP = {'mocap_rate_hz': 100.0, 'mocap_position_noise_m': 0.001, 'mocap_attitude_noise_rad': 0.002,
             'mocap_latency_s': 0.0}
FLY_ONLY = {'sim_node': ('lockstep_followers', 'lockstep_timeout_s')}  # what fly adds to the launch graph


@dataclasses.dataclass(frozen=True)
class NodeSpec:
    name: str                  # the node name (launch_ros: -r __node:=NAME), also its executable
    parameters: tuple = ()     # params file paths (str) and dicts, in the order launch_ros applies them
    namespace: str = ''        # '' or a fleet vehicle's name (launch_ros: -r __ns:=/NAMESPACE): its topics under it

    @property
    def fqn(self) -> str:
        """The fully qualified node name, e.g. /cf1/position_controller (a params file's section key)."""
        return f'/{self.namespace}/{self.name}' if self.namespace else f'/{self.name}'

    @property
    def executable(self) -> str:
        return self.name

    @property
    def package(self) -> str:
        return PACKAGES[self.name]

    @property
    def module(self) -> str:
        return MODULES[self.name]

    def merged_parameters(self) -> dict:
        """The parameters the node is given: each file's section for this node ('/**', '/**/NAME', its name or its
        fully qualified name), then each dict, the later one winning. rcl itself gives a file's plain `NAME:`
        section to /NAME only, never to /NS/NAME: a namespaced node is started with these merged into one dict
        (`launch_parameters`), so that it gets them all the same."""
        keys = ('/**', '/**/' + self.name, self.name, '/' + self.name) + (
            (self.fqn[1:], self.fqn) if self.namespace else ())
        merged = {}
        for entry in self.parameters:
            if isinstance(entry, dict):
                merged.update(entry)
                continue
            data = load_yaml(entry) or {}
            for key in keys:
                merged.update(parameters_of(data, key))
        return merged

    def launch_parameters(self) -> list:
        """What launch_ros and ros_arguments pass (files and dicts, in order): the parameters as given; under a
        namespace merged_parameters as one dict (launch_ros writes it under '/**'), since rcl would skip the
        files' `NAME:` sections there (test_launch_graph checks this against rcl)."""
        if not self.namespace:
            return list(self.parameters)
        return [self.merged_parameters()]

    def ros_arguments(self, out_dir: Path) -> list[str]:
        """`--ros-args -r __node:=NAME [-r __ns:=/NS] --params-file ...` as launch_ros gives them (dicts written
        under out_dir)."""
        args = ['--ros-args', '-r', f'__node:={self.name}']
        if self.namespace:
            args += ['-r', f'__ns:=/{self.namespace}']
        prefix = f'{self.namespace}_{self.name}' if self.namespace else self.name
        for i, entry in enumerate(self.launch_parameters()):
            if isinstance(entry, dict):
                path = Path(out_dir) / f'{prefix}_params_{i}.yaml'
                path.write_text(yaml.safe_dump(params_content('/**', entry), sort_keys=False))
                entry = str(path)
            args += ['--params-file', str(entry)]
        return args


NAMESPACE_COMPONENT = re.compile(r'[A-Za-z_][A-Za-z0-9_]*')


def join_namespace(base: str, namespace: str) -> str:
    """namespace under base as rcl resolves it ('' = the root; no leading '/'): an absolute namespace stands on its
    own. Raises ValueError naming a namespace that is no ROS name."""
    if namespace.startswith('/'):
        base = ''
    parts = [p for p in f'{base}/{namespace}'.split('/') if p]
    for part in parts:
        if not NAMESPACE_COMPONENT.fullmatch(part):
            raise ValueError(f'namespace {namespace!r} refused: {part!r} is no ROS name component (a letter or _, then '
                             'letters, digits, _)')
    return '/'.join(parts)


def absolute_config_paths(params: dict) -> dict:
    """params with the config files they name (vehicle, disturbances_file: relative to config/'s root) made
    absolute, as the nodes resolve them."""
    return {k: str(resolve_config(v)) if k in CONFIG_PATH_PARAMETERS and v and not Path(v).is_absolute() else v
            for k, v in params.items()}


def config(name: str) -> str:
    """A file of config/ (installed share/quad_bringup/config first, then the checkout)."""
    return str(resolve_config(Path('config') / name))


def profile_controller(control_profile) -> str | None:
    """The `controller` a control profile sets, or None."""
    if not control_profile or not Path(control_profile).is_file():   # a missing file is refused by its caller
        return None
    from quad_control.parameters import profile_parameters

    return profile_parameters(load_yaml(control_profile)).get('controller')


def controller_and_profile(controller: str | None, control_profile) -> tuple[str, str | None]:
    """--controller if given, else the profile's `controller`, else pd; a controller named without a profile
    flies its default profile (se3: the robust control_se3.yaml; pd and pid: the seed's gains). An unknown
    controller is refused here, before any node starts."""
    if controller:   # the node's own rule for its `controller` parameter (pure Python: no controller is imported)
        from quad_common.params import check_value
        from quad_control.controller_names import CONTROLLER_PARAM

        if reason := check_value(CONTROLLER_PARAM, controller):
            raise ValueError(reason)
    if control_profile:
        return controller or profile_controller(control_profile) or 'pd', str(control_profile)
    controller = controller or 'pd'
    return controller, config(DEFAULT_PROFILES[controller]) if controller in DEFAULT_PROFILES else None


def sim_graph(mission_path, *, controller: str | None = None, control_profile=None, vehicle=None,
              mode: str = 'lockstep', rtf: float = 1.0, speed_mps: float | None = None,
              extra: dict | None = None) -> list[NodeSpec]:
    """The simulated flight: trajectory_node, sim_node and position_controller on simulated time.

    vehicle: the vehicle file of all three (default: the mission's); the world and the robot radius are the
    mission's; mode lockstep (as fast as the graph goes; fly) or realtime at `rtf`; extra: {node: {param: value}}
    set last (fly's lockstep followers)."""
    from quad_trajectory.mission import load_mission

    if mode not in SIM_MODES:
        raise ValueError(f'mode {mode!r} refused: must be one of {", ".join(SIM_MODES)}')
    if not rtf > 0:
        raise ValueError(f'rtf {rtf!r} refused: must be > 0')
    mission = load_mission(mission_path)
    vehicle = str(Path(vehicle).resolve()) if vehicle else mission.vehicle_path or config('vehicles/crazyflie.yaml')
    controller, profile = controller_and_profile(controller, control_profile)
    lockstep = mode == 'lockstep'
    sim_time = {'use_sim_time': True}
    trajectory = {**sim_time, 'mission_file': str(Path(mission_path).resolve()), 'vehicle_file': vehicle}
    if speed_mps is not None:
        trajectory['speed_mps'] = float(speed_mps)
    nodes = {
        'trajectory_node': [config(CONFIG_FILES['trajectory_node']), trajectory],
        'sim_node': [config(CONFIG_FILES['sim_node']), {
            **sim_time, 'mode': mode, 'rtf': float(rtf), 'vehicle': vehicle,
            'initial_position': [float(v) for v in mission.initial_position],
            'world': mission.world_path or '', 'robot_radius_m': float(mission.options.robot_radius_m)}],
        'position_controller': [config(CONFIG_FILES['position_controller']), *([profile] if profile else []), {
            **sim_time, 'controller': controller, 'lockstep': lockstep, 'wait_for_trajectory': lockstep,
            'vehicle': vehicle}],
    }
    for name, values in (extra or {}).items():
        nodes[name].append(dict(values))
    return [NodeSpec(name, tuple(params)) for name, params in nodes.items()]


def fleet_sim_graph(fleet_path, *, speed_mps: float | None = None, sim: dict | None = None) -> list[NodeSpec]:
    """A fleet's simulated flight: one sim_node stepping every vehicle under one /clock (vehicle_names: each
    vehicle's topics under its name), and under each vehicle's namespace its trajectory_node (fleet_vehicle: its
    part of the fleet file) and position_controller (its controller and profile, its vehicle file). sim: sim_node
    parameters set last (fleet runs: the lockstep followers, duration_s)."""
    from quad_trajectory.fleet import load_fleet

    fleet = load_fleet(fleet_path)
    sim_time = {'use_sim_time': True}
    vehicle_files = [v.mission.vehicle_path or config('vehicles/crazyflie.yaml') for v in fleet.vehicles]
    worlds = {v.mission.world_path or '' for v in fleet.vehicles}
    if len(worlds) > 1:
        raise ValueError(f'{fleet_path}: the vehicles name different worlds ({", ".join(sorted(worlds))}): one '
                         'simulator flies them in one world')
    nodes = [NodeSpec('sim_node', (config(CONFIG_FILES['sim_node']), {
        **sim_time, 'mode': 'lockstep', 'vehicle': vehicle_files[0], 'world': worlds.pop(),
        'vehicle_names': fleet.names, 'vehicle_files': vehicle_files,
        'initial_positions': [float(x) for v in fleet.vehicles for x in v.mission.initial_position],
        'robot_radii_m': [float(v.radius_m) for v in fleet.vehicles], **(sim or {})}))]
    for v, vehicle in zip(fleet.vehicles, vehicle_files):
        controller, profile = controller_and_profile(v.controller, v.profile_path)
        trajectory = {**sim_time, 'mission_file': str(Path(fleet_path).resolve()), 'fleet_vehicle': v.name,
                      'vehicle_file': vehicle}
        if speed_mps is not None:
            trajectory['speed_mps'] = float(speed_mps)
        nodes.append(NodeSpec('trajectory_node', (config(CONFIG_FILES['trajectory_node']), trajectory), v.name))
        nodes.append(NodeSpec('position_controller', (
            config(CONFIG_FILES['position_controller']), *([profile] if profile else []),
            {**sim_time, 'controller': controller, 'lockstep': True, 'wait_for_trajectory': True,
             'vehicle': vehicle}), v.name))
    return nodes


def fly_graph(mission_path, *, sim: dict | None = None, controller_params: dict | None = None,
              **kwargs) -> list[NodeSpec]:
    """sim_graph (lockstep; kwargs: its controller, control_profile, vehicle, speed_mps) plus what only fly has:
    the recorder and fly's monitor as the simulator's lockstep followers, a longer lockstep timeout, then `sim`
    (sim_node parameters: the plant, disturbances, a sweep's) and `controller_params` (position_controller's, last).
    A controller flying from motion capture (state_source external_pose) gets the simulator's stand-in
    (FLY_MOCAP under `sim`)."""
    extra = {'lockstep_followers': f'{RECORDER},{MONITOR}', 'lockstep_timeout_s': FLY_LOCKSTEP_TIMEOUT_S}
    nodes = {'sim_node': {**extra, **(sim or {})}, 'position_controller': dict(controller_params or {})}
    specs = sim_graph(mission_path, extra=nodes, **kwargs)
    controller = next(s for s in specs if s.name == 'position_controller').merged_parameters()
    if controller.get('state_source') == 'external_pose':
        nodes['sim_node'] = {**extra, **FLY_MOCAP, **(sim or {})}
        specs = sim_graph(mission_path, extra=nodes, **kwargs)
    return specs


def params_file_content(nodes: list[NodeSpec]) -> dict:
    """{node: {ros__parameters: ...}}: what each node ends up with, the config files it names made absolute (a
    params file that holds on its own, e.g. a run directory's params.yaml)."""
    content = {}
    for spec in nodes:
        content.update(params_content(spec.fqn if spec.namespace else spec.name,
                                      absolute_config_paths(spec.merged_parameters())))
    return content


def bridge_graph(autopilot: str, mission_path, *, vehicle=None, control_profile=None, fcu_url: str = '',
                 hover_throttle: float | None = None, vehicle_params: str = '',
                 controller: str | None = None, external_pose: str = EXTERNAL_POSE_OFF,
                 state_source: str | None = None) -> list[NodeSpec]:
    """A real (or emulated) vehicle: trajectory_node and position_controller on wall-clock time and
    mavlink_bridge from config/bridge_<autopilot>.yaml. The plan runs only while the bridge's hand-over is
    active (vehicle/engaged), so the nodes may start in any order and `offboard` may come at any time.

    vehicle: the vehicle file of the planner's limits and the controller (default px4_quad.yaml);
    control_profile: over control.yaml (default control_real.yaml); controller: over the profile's (a user class:
    docs/plugins.md); fcu_url, hover_throttle, vehicle_params: the bridge's parameters when given.
    external_pose: off, or the frame (enu, y_up) of the motion capture on external/pose that the bridge forwards to
    the autopilot's estimator; state_source: over the profile's (odom, external_pose: the controller flies from that
    pose, in the bridge's frame). With external_pose on and state_source set by neither, the controller flies from
    the pose: it is the autopilot's estimate's own source without the estimator's and the telemetry's delays
    (docs/benchmarks.md, indoor flight through the graph). A controller on external_pose with external_pose off is
    refused: the autopilot would hold and fail safe on an estimate without the pose the controller flies from."""
    from quad_common.mocap_frames import FRAMES
    from quad_control.parameters import STATE_SOURCES

    if autopilot not in AUTOPILOTS:
        raise ValueError(f'autopilot {autopilot!r} refused: must be one of {", ".join(AUTOPILOTS)}')
    if external_pose not in (EXTERNAL_POSE_OFF, *FRAMES):
        raise ValueError(f'external_pose {external_pose!r} refused: must be one of '
                         f'{", ".join((EXTERNAL_POSE_OFF, *FRAMES))}')
    if state_source is not None and state_source not in STATE_SOURCES:
        raise ValueError(f'state_source {state_source!r} refused: must be one of {", ".join(STATE_SOURCES)}')
    vehicle = str(Path(vehicle).resolve()) if vehicle else config(REAL_VEHICLE)
    profile = str(control_profile) if control_profile else config(REAL_VEHICLE_PROFILE)
    wall = {'use_sim_time': False}
    bridge = {**wall, 'external_pose_enabled': external_pose != EXTERNAL_POSE_OFF}
    if external_pose != EXTERNAL_POSE_OFF:
        bridge['external_pose_frame'] = external_pose
    for key, value in (('fcu_url', fcu_url), ('hover_throttle', hover_throttle), ('vehicle_params', vehicle_params)):
        if value not in (None, ''):
            bridge[key] = float(value) if key == 'hover_throttle' else str(value)
    control = {**wall, 'lockstep': False, 'wait_for_engagement': True, 'vehicle': vehicle,
               **({'controller': controller} if controller else {}),
               **({'state_source': state_source} if state_source else {})}
    nodes = [
        NodeSpec('trajectory_node', (config(CONFIG_FILES['trajectory_node']),
                                     {**wall, 'mission_file': str(Path(mission_path).resolve()),
                                      'vehicle_file': vehicle})),
        NodeSpec('position_controller', (config(CONFIG_FILES['position_controller']), profile, control)),
        NodeSpec('mavlink_bridge', (config(CONFIG_FILES['mavlink_bridge'].format(autopilot=autopilot)), bridge)),
    ]
    flies_from = nodes[1].merged_parameters().get('state_source')   # the argument's, else the profile's, or None
    if flies_from is None and external_pose != EXTERNAL_POSE_OFF:     # indoors: from the motion capture (above)
        flies_from = control['state_source'] = 'external_pose'
    if flies_from == 'external_pose':
        if external_pose == EXTERNAL_POSE_OFF:
            raise ValueError(f'state_source {"external_pose"!r} refused with external_pose {external_pose!r}: the '
                             'controller flies from the motion capture the bridge forwards (external_pose:=enu or '
                             'y_up, its frame)')
        control['external_pose_frame'] = external_pose    # one frame for the bridge's pose and the controller's
    return nodes


FLEET_BRIDGE_KEYS = ('autopilot', 'fcu_url', 'system_id')   # what each vehicle of a real fleet must have


def fleet_bridge_graph(fleet_path, *, control_profile=None, hover_throttle: float | None = None,
                       vehicle_params: str = '', external_pose: str = EXTERNAL_POSE_OFF,
                       state_source: str | None = None) -> list[NodeSpec]:
    """A fleet of real (or emulated) vehicles: per vehicle, under its name as namespace, bridge_graph's three
    nodes. trajectory_node flies its plan of the fleet file (`fleet_vehicle`; its start delay and altitude layer
    as the file deconflicts), position_controller its own controller and profile (else control_profile, else
    control_real.yaml), mavlink_bridge its `autopilot`'s config with its `fcu_url` and its MAVLink `system_id` as
    target_system (only that vehicle is commanded and listened to, whoever else is on the link) and as
    source_system (the companion computer of that vehicle). The fleet's plans are checked for separation first
    (quad_trajectory.fleet.plan_fleet): a conflict is refused as `quadflight plan` refuses it. external_pose,
    state_source: every vehicle's, as bridge_graph's (each reads external/pose under its namespace)."""
    from quad_trajectory.fleet import load_fleet, plan_fleet

    fleet = load_fleet(fleet_path)
    for i, v in enumerate(fleet.vehicles):
        for key in FLEET_BRIDGE_KEYS:
            if getattr(v, key) is None:
                raise ValueError(f'{fleet.path}: vehicles[{i}] ({v.name}): {key} is missing: a vehicle flown through '
                                 f'a bridge needs {", ".join(FLEET_BRIDGE_KEYS)} (docs/bridge.md, "Fleets of real '
                                 'vehicles")')
    refusal = plan_fleet(fleet).refusal()
    if refusal:
        raise ValueError(refusal)
    path = str(Path(fleet_path).resolve())
    nodes = []
    for v in fleet.vehicles:
        vehicle = v.mission.vehicle_path or config(REAL_VEHICLE)
        specs = bridge_graph(v.autopilot, path, vehicle=vehicle, control_profile=v.profile_path or control_profile,
                             fcu_url=v.fcu_url, hover_throttle=hover_throttle, vehicle_params=vehicle_params,
                             external_pose=external_pose, state_source=state_source)
        extra = {'trajectory_node': {'fleet_vehicle': v.name},
                 'position_controller': {'controller': v.controller} if v.controller else {},
                 'mavlink_bridge': {'autopilot': v.autopilot, 'target_system': v.system_id,
                                    'source_system': v.system_id}}
        nodes += [NodeSpec(s.name, s.parameters + (extra[s.name],), v.name) for s in specs]
    return nodes


# --- launch arguments: (name, default, description); '' = the graph's own default ----------------------------
SIM_LAUNCH_ARGUMENTS = (
    ('mission', 'missions/maze.yaml', 'mission YAML: a path, or one under config/'),
    ('controller', '', 'pd | pid | se3 | package.module:Class (docs/plugins.md); empty: the control profile\'s, '
                       'else pd'),
    ('control_profile', '', 'params file over control.yaml; empty: se3 flies control_se3.yaml, pd and pid the '
                            'seed\'s gains'),
    ('vehicle', '', 'vehicle YAML of the planner\'s limits, the controller and the simulator; empty: the mission\'s'),
    ('mode', 'lockstep', 'lockstep (as fast as the graph goes) | realtime'),
    ('rtf', '1.0', 'realtime: simulated seconds per wall-clock second'),
)
INDOOR_LAUNCH_ARGUMENTS = (
    ('external_pose', EXTERNAL_POSE_OFF, 'off | enu | y_up: the bridge forwards the motion capture on external/pose '
                                         'in this frame to the autopilot\'s estimator (docs/bridge.md "Indoor '
                                         'flight")'),
    ('state_source', '', 'odom | external_pose: what position_controller flies from (external_pose: the same '
                         'motion capture, needs external_pose:=enu or y_up); empty: the profile\'s, and '
                         'external_pose where external_pose is on and the profile does not say'),
)
BRIDGE_LAUNCH_ARGUMENTS = (
    ('mission', 'missions/maze.yaml', 'mission YAML: a path, or one under config/'),
    ('vehicle', REAL_VEHICLE, 'vehicle YAML of the planner\'s limits and the controller'),
    ('control_profile', REAL_VEHICLE_PROFILE, 'position_controller profile over control.yaml'),
    ('controller', '', 'pd | pid | se3 | package.module:Class (docs/plugins.md) over the profile\'s; empty: the '
                       'profile\'s'),
    ('fcu_url', '', 'the autopilot\'s MAVLink address; empty: the bridge config\'s'),
    ('hover_throttle', '', 'the vehicle\'s hover thrust (PX4 MPC_THR_HOVER, ArduPilot MOT_THST_HOVER); empty: '
                           'the bridge config\'s'),
    ('vehicle_params', '', 'check | adopt | ignore the vehicle\'s semantic parameters; empty: the bridge config\'s'),
    *INDOOR_LAUNCH_ARGUMENTS,
)
FLEET_LAUNCH_ARGUMENTS = (
    ('mission', 'missions/fleets/sitl3.yaml', 'fleet YAML whose vehicles have autopilot, fcu_url and system_id: a '
                                              'path, or one under config/'),
    ('control_profile', '', 'position_controller profile over control.yaml of the vehicles without their own '
                            'profile; empty: ' + REAL_VEHICLE_PROFILE),
    ('hover_throttle', '', 'every vehicle\'s hover thrust; empty: the bridge configs\''),
    ('vehicle_params', '', 'check | adopt | ignore the vehicles\' semantic parameters; empty: the bridge configs\''),
    *INDOOR_LAUNCH_ARGUMENTS,
)
FLEET_SIM_LAUNCH_ARGUMENTS = (
    ('mission', 'missions/fleets/formation4.yaml', 'fleet YAML: a path, or one under config/'),
)
NAMESPACE_ARGUMENT = ('namespace', '', 'every node under this namespace (relative: under an including file\'s '
                                       'PushRosNamespace); the parameter files apply there as at the root')
# launch files whose nodes do not end the launch when they exit: each vehicle's bridge lands its vehicle alone
FAILSAFE_PER_VEHICLE = ('fleet',)
LAUNCH_FILES = {'sim': SIM_LAUNCH_ARGUMENTS, 'px4': BRIDGE_LAUNCH_ARGUMENTS, 'ardupilot': BRIDGE_LAUNCH_ARGUMENTS,
                'fleet': FLEET_LAUNCH_ARGUMENTS, 'fleet_sim': FLEET_SIM_LAUNCH_ARGUMENTS}


def config_path(value: str) -> str:
    """A file argument: the path as given if it exists, else the same path under config/."""
    if not value:
        return ''
    return str(Path(value).resolve()) if Path(value).is_file() else config(value)


def graph_from_arguments(kind: str, args: dict) -> list[NodeSpec]:
    """The graph of launch/<kind>.launch.py from its launch arguments (strings, as launch gives them)."""
    if kind == 'sim':
        try:
            rtf = float(args['rtf'])
        except ValueError:
            raise ValueError(f'rtf {args["rtf"]!r} refused: must be a number') from None
        return sim_graph(config_path(args['mission']), controller=args['controller'] or None,
                         control_profile=config_path(args['control_profile']) or None,
                         vehicle=config_path(args['vehicle']) or None, mode=args['mode'], rtf=rtf)
    if kind == 'fleet_sim':
        from quad_trajectory.fleet import load_fleet, plan_fleet

        refusal = plan_fleet(load_fleet(config_path(args['mission']))).refusal()
        if refusal:
            raise ValueError(refusal)
        return fleet_sim_graph(config_path(args['mission']))
    hover = args['hover_throttle']
    try:
        hover_throttle = float(hover) if hover else None
    except ValueError:
        raise ValueError(f'hover_throttle {hover!r} refused: must be a number') from None
    indoor = {'external_pose': args['external_pose'], 'state_source': args['state_source'] or None}
    if kind == 'fleet':
        return fleet_bridge_graph(config_path(args['mission']), control_profile=config_path(args['control_profile'])
                                  or None, hover_throttle=hover_throttle, vehicle_params=args['vehicle_params'],
                                  **indoor)
    return bridge_graph(kind, config_path(args['mission']), vehicle=config_path(args['vehicle']),
                        control_profile=config_path(args['control_profile']), fcu_url=args['fcu_url'],
                        hover_throttle=hover_throttle, vehicle_params=args['vehicle_params'],
                        controller=args['controller'] or None, **indoor)
