"""Declared parameters without ROS: a node's table of specs (Param), the one check of a value against its spec,
and the section of a params file that holds a node's parameters.

A value that is non-finite, outside its range, or not one of its choices is refused with a reason naming the
parameter, the value and the rule. quad_common.ros_params declares a table on a node (ParameterSet).
"""

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Param:
    name: str
    default: Any
    description: str
    min: float | None = None
    max: float | None = None
    choices: tuple | None = None
    read_only: bool = False
    length: int | None = None  # required length of an array value
    check: Callable[[Any], str | None] | None = None  # a rule of its own: the reason a value is refused, or None


def check_value(spec: Param, value) -> str | None:
    """The reason `value` is refused for `spec`, or None if it is acceptable."""
    values = list(value) if isinstance(value, (list, tuple)) else [value]
    if spec.length is not None and isinstance(value, (list, tuple)) and len(values) != spec.length:
        return f'{spec.name} = {value!r} refused: needs {spec.length} values'
    for v in values:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            continue
        if not math.isfinite(v):
            return f'{spec.name} = {value!r} refused: must be finite'
        if spec.min is not None and v < spec.min:
            return f'{spec.name} = {value!r} refused: must be >= {spec.min}'
        if spec.max is not None and v > spec.max:
            return f'{spec.name} = {value!r} refused: must be <= {spec.max}'
    if spec.choices is not None and value not in spec.choices:
        return f'{spec.name} = {value!r} refused: must be one of {", ".join(map(str, spec.choices))}'
    if spec.check is not None:
        return spec.check(value)
    return None


def parameters_of(content: dict, node: str) -> dict:
    """The `node: ros__parameters:` mapping of a params file's content ({} when absent)."""
    return ((content or {}).get(node) or {}).get('ros__parameters') or {}


def params_content(node: str, values: dict) -> dict:
    """A params file's content setting `values` on `node`."""
    return {node: {'ros__parameters': dict(values)}}
