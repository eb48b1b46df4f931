"""A stand-in for the parts of `launch` / `launch_ros` the launch files use (neither has a PyPI wheel), with
their semantics as launch 3.x and launch_ros 0.26 (ROS 2 Jazzy) define them:

- LaunchDescription(entities): its entities are visited in order.
- DeclareLaunchArgument(name, default_value, description): sets the launch configuration `name` to the default
  unless the command line (`name:=value`) already set it; no default and no value is an error.
- LaunchConfiguration(name).perform(context): the configuration's value (an undeclared one is an error).
- OpaqueFunction(function): function(context) returns more entities, visited in turn.
- GroupAction(actions, scoped=True): the actions, with the launch configurations (and the pushed ROS namespace)
  they set undone after them when scoped.
- IncludeLaunchDescription(PythonLaunchDescriptionSource(path), launch_arguments=[(name, value)]): sets each
  argument as a launch configuration, then visits the file's generate_launch_description().
- launch_ros PushRosNamespace(namespace): the launch configuration `ros_namespace` becomes namespace if absolute,
  else the previous ros_namespace joined with it (launch_ros.actions.PushRosNamespace).
- launch_ros Node(package, executable, name, namespace, parameters, ...): runs `<prefix of package>/lib/<package>/
  <executable> --ros-args -r __node:=<name> [-r __ns:=/<namespace>] --params-file F ...`, one --params-file per
  parameters entry in order: a string is a file path, a dict is written to a temporary file as
  {'/**': {'ros__parameters': dict}}; a relative namespace (or none) is prefixed with the pushed `ros_namespace`
  and made absolute (a leading '/'). on_exit is recorded (LaunchedNode.on_exit), not modelled.
- launch.actions.Shutdown(reason=...): recorded as an on_exit action.

evaluate(launch_file, **arguments) -> [LaunchedNode]; LaunchedNode.command(tmp_dir) -> argv.
"""

import importlib.util
import sys
import types
from dataclasses import dataclass
from pathlib import Path

import yaml


class LaunchError(RuntimeError):
    pass


class Context:
    def __init__(self, arguments: dict):
        self.launch_configurations = dict(arguments)
        self.stack = []


class LaunchDescription:
    def __init__(self, initial_entities=None):
        self.entities = list(initial_entities or [])

    def visit(self, context):
        return list(self.entities)


class _PushLaunchConfigurations:
    def visit(self, context):
        context.stack.append(dict(context.launch_configurations))
        return []


class _PopLaunchConfigurations:
    def visit(self, context):
        context.launch_configurations = context.stack.pop()
        return []


class GroupAction:
    def __init__(self, actions, *, scoped=True, forwarding=True, launch_configurations=None, **_):
        if launch_configurations or not forwarding:
            raise LaunchError('the stand-in models GroupAction(actions, scoped=...) only')
        self.actions, self.scoped = list(actions), scoped

    def visit(self, context):
        if not self.scoped:
            return list(self.actions)
        return [_PushLaunchConfigurations(), *self.actions, _PopLaunchConfigurations()]


class PythonLaunchDescriptionSource:
    def __init__(self, launch_file_path):
        if not isinstance(launch_file_path, (str, Path)):
            raise LaunchError('the stand-in models a plain path')
        self.path = Path(launch_file_path)


class IncludeLaunchDescription:
    def __init__(self, launch_description_source, *, launch_arguments=None):
        self.source, self.arguments = launch_description_source, list(launch_arguments or [])

    def visit(self, context):
        for name, value in self.arguments:
            context.launch_configurations[str(name)] = str(value)
        return [_load(self.source.path)]


class PushRosNamespace:
    def __init__(self, namespace):
        if not isinstance(namespace, str):
            raise LaunchError('the stand-in models a plain string namespace')
        self.namespace = namespace

    def visit(self, context):
        pushed = self.namespace.strip()
        previous = context.launch_configurations.get('ros_namespace')
        if not pushed.startswith('/') and previous:
            pushed = previous.rstrip('/') + '/' + pushed
        context.launch_configurations['ros_namespace'] = '/' + pushed.strip('/') if pushed.strip('/') else '/'
        return []


class Shutdown:
    def __init__(self, *, reason='reason not given'):
        self.reason = reason


class DeclareLaunchArgument:
    def __init__(self, name, *, default_value=None, description='', choices=None):
        self.name, self.default_value, self.description, self.choices = name, default_value, description, choices

    def visit(self, context):
        if self.name not in context.launch_configurations:
            if self.default_value is None:
                raise LaunchError(f"Required launch argument '{self.name}' was not provided")
            context.launch_configurations[self.name] = str(self.default_value)
        value = context.launch_configurations[self.name]
        if self.choices is not None and value not in self.choices:
            raise LaunchError(f"Argument '{self.name}' expected one of {self.choices}, got '{value}'")
        return []


class LaunchConfiguration:
    def __init__(self, variable_name, default=None):
        self.name, self.default = variable_name, default

    def perform(self, context):
        if self.name in context.launch_configurations:
            return context.launch_configurations[self.name]
        if self.default is not None:
            return str(self.default)
        raise LaunchError(f"launch configuration '{self.name}' does not exist")


class OpaqueFunction:
    def __init__(self, *, function, args=None, kwargs=None):
        self.function, self.args, self.kwargs = function, args or [], kwargs or {}

    def visit(self, context):
        return list(self.function(context, *self.args, **self.kwargs) or [])


@dataclass
class LaunchedNode:
    package: str
    executable: str
    name: str
    parameters: list
    namespace: str = ''    # '' or absolute (/cf1)
    on_exit: object = None

    def command(self, tmp_dir: Path, prefix: Path) -> list[str]:
        """The argv launch_ros runs (prefix: the package's install prefix, as ament_index gives it)."""
        argv = [str(prefix / 'lib' / self.package / self.executable), '--ros-args', '-r', f'__node:={self.name}']
        if self.namespace:
            argv += ['-r', f'__ns:={self.namespace}']
        for i, entry in enumerate(self.parameters):
            if isinstance(entry, dict):
                path = Path(tmp_dir) / f'launch_params_{self.namespace.strip("/").replace("/", "_")}_{self.name}_{i}'
                path.write_text(yaml.dump({'/**': {'ros__parameters': entry}}, default_flow_style=False))
                entry = path
            elif not isinstance(entry, (str, Path)):
                raise LaunchError(f'invalid normalized parameters {entry!r}')
            argv += ['--params-file', str(entry)]
        return argv


class Node:
    def __init__(self, *, package, executable, name=None, namespace=None, parameters=None, remappings=None,
                 arguments=None, output='log', on_exit=None, **_):
        if remappings or arguments:
            raise LaunchError('the stand-in does not model remappings or arguments')
        if namespace and not isinstance(namespace, str):
            raise LaunchError(f'namespace {namespace!r}: the stand-in models a plain string')
        self.namespace = namespace
        self.launched = LaunchedNode(package, executable, name, list(parameters or []), '', on_exit)

    def visit(self, context):
        namespace = self.namespace or ''
        base = context.launch_configurations.get('ros_namespace') or ''
        if not namespace.startswith('/'):
            namespace = base.rstrip('/') + '/' + namespace
        namespace = namespace.strip('/')
        self.launched.namespace = '/' + namespace if namespace else ''
        return []


def _modules():
    launch = types.ModuleType('launch')
    launch.LaunchDescription = LaunchDescription
    actions = types.ModuleType('launch.actions')
    actions.DeclareLaunchArgument, actions.OpaqueFunction = DeclareLaunchArgument, OpaqueFunction
    actions.GroupAction, actions.IncludeLaunchDescription, actions.Shutdown = (GroupAction, IncludeLaunchDescription,
                                                                               Shutdown)
    substitutions = types.ModuleType('launch.substitutions')
    substitutions.LaunchConfiguration = LaunchConfiguration
    sources = types.ModuleType('launch.launch_description_sources')
    sources.PythonLaunchDescriptionSource = PythonLaunchDescriptionSource
    launch.actions, launch.substitutions, launch.launch_description_sources = actions, substitutions, sources
    launch_ros = types.ModuleType('launch_ros')
    ros_actions = types.ModuleType('launch_ros.actions')
    ros_actions.Node, ros_actions.PushRosNamespace = Node, PushRosNamespace
    launch_ros.actions = ros_actions
    return {'launch': launch, 'launch.actions': actions, 'launch.substitutions': substitutions,
            'launch.launch_description_sources': sources, 'launch_ros': launch_ros, 'launch_ros.actions': ros_actions}


def _load(launch_file: Path) -> LaunchDescription:
    spec = importlib.util.spec_from_file_location(f'launch_file_{Path(launch_file).stem}', launch_file)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.generate_launch_description()


def evaluate(launch_file: Path, **arguments) -> list[LaunchedNode]:
    """The nodes `ros2 launch <launch_file> name:=value ...` starts, in order."""
    saved = {name: sys.modules.get(name) for name in [*_modules(), 'quad_bringup.running.launch_graph']}
    sys.modules.update(_modules())
    sys.modules.pop('quad_bringup.running.launch_graph', None)   # imported afresh against the stand-in
    try:
        context, nodes = Context({k: str(v) for k, v in arguments.items()}), []
        pending = [_load(launch_file)]
        while pending:
            entity = pending.pop(0)
            pending[:0] = entity.visit(context)
            if isinstance(entity, Node):
                nodes.append(entity.launched)
        return nodes
    finally:
        for name, module in saved.items():
            if module is None:
                sys.modules.pop(name, None)
            else:
                sys.modules[name] = module
