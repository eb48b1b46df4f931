"""A node's declared, validated ROS parameters (ParameterSet): the table of quad_common.params on an rclpy node.

A refused run-time value leaves the node with its previous value; at start-up the same check raises
ValueError, so a bad params file stops the node with its reason.
"""

from collections.abc import Callable

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.parameter import Parameter

from quad_common.params import Param, check_value


def _descriptor(spec: Param) -> ParameterDescriptor:
    """A scalar is declared with dynamic typing so that a value of the wrong type reaches ParameterSet's check, which
    names the parameter (rclpy's own type check says only "Wrong parameter type"); arrays keep rclpy's static type."""
    d = ParameterDescriptor(description=spec.description, read_only=spec.read_only,
                            dynamic_typing=isinstance(spec.default, (bool, int, float, str)))
    if spec.choices is not None:
        d.additional_constraints = 'one of: ' + ', '.join(map(str, spec.choices))
    scalar = not isinstance(spec.default, (list, tuple, str, bool))
    if scalar and (spec.min is not None or spec.max is not None):
        lo = spec.min if spec.min is not None else -1e300
        hi = spec.max if spec.max is not None else 1e300
        if isinstance(spec.default, int):
            d.integer_range = [IntegerRange(from_value=int(max(lo, -2**62)), to_value=int(min(hi, 2**62)), step=0)]
        else:
            d.floating_point_range = [FloatingPointRange(from_value=float(lo), to_value=float(hi), step=0.0)]
    return d


def _declare(node, spec: Param):
    """Declares spec on node; its value. An array typed by its default (Parameter.Type.DOUBLE_ARRAY, ...) and not
    given is set to an empty array of that type: rclpy's parameter service answers no get_parameters request that
    names an unset parameter (`ros2 param dump` prints {}), and rclpy infers an empty list's type as bytes."""
    if not isinstance(spec.default, Parameter.Type):
        return node.declare_parameter(spec.name, spec.default, _descriptor(spec)).value
    writable = _descriptor(spec)
    writable.read_only = False
    value = node.declare_parameter(spec.name, spec.default, writable).value
    if value is None:
        node.set_parameters([Parameter(spec.name, spec.default, [])])
        value = []
    if spec.read_only:
        final = _descriptor(spec)
        final.type = spec.default.value
        node.set_descriptor(spec.name, final)
    return value


def _typed(spec: Param, value):
    """An integer given for a float parameter (dynamic typing lets `kp_x: 2` through) as the float it means."""
    if isinstance(spec.default, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


def params_files(argv) -> list[str]:
    """The `--params-file` paths of a command line's ROS arguments."""
    return [argv[i + 1] for i, a in enumerate(argv[:-1]) if a == '--params-file']


def check_sections_reach(node, argv=None):
    """Raises ValueError when a params file of the command line has a plain `NAME:` section that sets parameters
    of this node while it runs in a namespace: rcl gives such a section to /NAME only, so the node would run on its
    built-in defaults without a word (e.g. `ros2 run ... -r __ns:=/uav2 --params-file control_real.yaml`). A section
    that sets nothing (config/control.yaml: the defaults) loses nothing."""
    import sys

    from quad_common.params import parameters_of
    from quad_common.yaml_io import load_yaml

    namespace, name = node.get_namespace(), node.get_name()
    if namespace == '/':
        return
    fqn = f'{namespace}/{name}'
    for path in params_files(sys.argv if argv is None else argv):
        try:
            content = load_yaml(path) or {}
        except (OSError, ValueError):
            continue   # rcl itself refuses a file it cannot read
        if isinstance(content, dict) and parameters_of(content, name):
            raise ValueError(f'--params-file {path}: its `{name}:` section reaches /{name} only, not {fqn} (rcl): '
                             f'key it `/**/{name}:` or `{fqn}:`, or start the node through a launch file (it hands '
                             'a namespaced node its files merged)')


class ParameterSet:
    """Declares `specs` on `node`; `ps[name]` is the current value.

    `validate(values: dict)` may raise ValueError for rules across parameters (e.g. min < max);
    `on_change(changed: dict)` is called after an accepted run-time update.
    """

    def __init__(self, node, specs, validate: Callable[[dict], None] | None = None,
                 on_change: Callable[[dict], None] | None = None):
        self._node = node
        self._specs = {s.name: s for s in specs}
        self._validate = validate
        self._on_change = on_change
        self.values = {}
        check_sections_reach(node)
        for s in specs:
            try:
                value = _declare(node, s)
            except Exception as exc:  # rclpy's own range check on a params-file value
                raise ValueError(f'parameter {s.name}: {exc}') from None
            reason = check_value(s, value)
            if reason:
                raise ValueError(reason)
            self.values[s.name] = _typed(s, value)
        if validate:
            validate(dict(self.values))
        node.add_on_set_parameters_callback(self._on_set)
        node.add_post_set_parameters_callback(self._post_set)

    def __getitem__(self, name):
        return self.values[name]

    def _on_set(self, params) -> SetParametersResult:
        proposed = dict(self.values)
        for p in params:
            spec = self._specs.get(p.name)
            if spec is None:
                continue
            reason = check_value(spec, p.value)
            if reason:
                return self._refuse(f'{reason} (kept {self.values[p.name]!r})')
            proposed[p.name] = p.value
        if self._validate:
            try:
                self._validate(proposed)
            except ValueError as exc:
                return self._refuse(f'{exc} (previous values kept)')
        return SetParametersResult(successful=True)

    def _refuse(self, reason) -> SetParametersResult:
        self._node.get_logger().error(reason)
        return SetParametersResult(successful=False, reason=reason)

    def _post_set(self, params):
        changed = {p.name: _typed(self._specs[p.name], p.value) for p in params if p.name in self._specs}
        self.values.update(changed)
        if changed and self._on_change:
            self._on_change(changed)
