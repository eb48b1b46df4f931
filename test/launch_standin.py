"""A stand-in for the parts of `launch` / `launch_ros` the launch files use (neither has a PyPI wheel), with
their semantics as launch 3.x and launch_ros 0.26 (ROS 2 Jazzy) define them:

- LaunchDescription(entities): its entities are visited in order.
- DeclareLaunchArgument(name, default_value, description): sets the launch configuration `name` to the default
  unless the command line (`name:=value`) already set it; no default and no value is an error.
- LaunchConfiguration(name).perform(context): the configuration's value (an undeclared one is an error).
- OpaqueFunction(function): function(context) returns more entities, visited in turn.
- launch_ros Node(package, executable, name, namespace, parameters, ...): runs `<prefix of package>/lib/<package>/
  <executable> --ros-args -r __node:=<name> [-r __ns:=/<namespace>] --params-file F ...`, one --params-file per
  parameters entry in order: a string is a file path, a dict is written to a temporary file as
  {'/**': {'ros__parameters': dict}}; a relative namespace is made absolute (a leading '/').

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


class LaunchDescription:
    def __init__(self, initial_entities=None):
        self.entities = list(initial_entities or [])


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
                 arguments=None, output='log', **_):
        if remappings or arguments:
            raise LaunchError('the stand-in does not model remappings or arguments')
        if namespace and not isinstance(namespace, str):
            raise LaunchError(f'namespace {namespace!r}: the stand-in models a plain string')
        namespace = ('/' + namespace.lstrip('/')).rstrip('/') if namespace else ''
        self.launched = LaunchedNode(package, executable, name, list(parameters or []), namespace)

    def visit(self, context):
        return []


def _modules():
    launch = types.ModuleType('launch')
    launch.LaunchDescription = LaunchDescription
    actions = types.ModuleType('launch.actions')
    actions.DeclareLaunchArgument, actions.OpaqueFunction = DeclareLaunchArgument, OpaqueFunction
    substitutions = types.ModuleType('launch.substitutions')
    substitutions.LaunchConfiguration = LaunchConfiguration
    launch.actions, launch.substitutions = actions, substitutions
    launch_ros = types.ModuleType('launch_ros')
    ros_actions = types.ModuleType('launch_ros.actions')
    ros_actions.Node = Node
    launch_ros.actions = ros_actions
    return {'launch': launch, 'launch.actions': actions, 'launch.substitutions': substitutions,
            'launch_ros': launch_ros, 'launch_ros.actions': ros_actions}


def evaluate(launch_file: Path, **arguments) -> list[LaunchedNode]:
    """The nodes `ros2 launch <launch_file> name:=value ...` starts, in order."""
    saved = {name: sys.modules.get(name) for name in [*_modules(), 'quad_bringup.launch_graph']}
    sys.modules.update(_modules())
    sys.modules.pop('quad_bringup.launch_graph', None)   # imported afresh against the stand-in
    try:
        spec = importlib.util.spec_from_file_location(f'launch_file_{Path(launch_file).stem}', launch_file)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        description = module.generate_launch_description()
        context, nodes = Context({k: str(v) for k, v in arguments.items()}), []
        pending = list(description.entities)
        while pending:
            entity = pending.pop(0)
            if isinstance(entity, Node):
                nodes.append(entity.launched)
            pending[:0] = entity.visit(context)
        return nodes
    finally:
        for name, module in saved.items():
            if module is None:
                sys.modules.pop(name, None)
            else:
                sys.modules[name] = module
