"""Declared parameters without ROS: a node's table of specs (Param), the one check of a value against its spec,
and the section of a params file that holds a node's parameters.

A value that is non-finite, outside its range, or not one of its choices is refused with a reason naming the
parameter, the value and the rule. quad_common.ros.ros_params declares a table on a node (ParameterSet).
"""

import math
import numbers
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


def _kind(example) -> tuple[str, Callable[[Any], bool]] | None:
    """(what a value must be, its test) for a default's type; None: no rule (e.g. a typed empty array)."""
    if isinstance(example, bool):
        return 'true or false', lambda v: isinstance(v, bool)
    if isinstance(example, numbers.Integral):
        return 'an integer', lambda v: isinstance(v, numbers.Integral) and not isinstance(v, bool)
    if isinstance(example, numbers.Real):
        return 'a number', lambda v: isinstance(v, numbers.Real) and not isinstance(v, bool)
    if isinstance(example, str):
        return 'text', lambda v: isinstance(v, str)
    return None


_PLURAL = {'true or false': 'true / false values', 'an integer': 'integers', 'a number': 'numbers', 'text': 'texts'}


def type_refusal(spec: Param, value) -> str | None:
    """The reason `value` is not of the type of spec's default (a number for a float, an integer for an int, ...;
    a list of them for a list), or None."""
    default = spec.default
    if isinstance(default, (list, tuple)):
        if isinstance(value, (str, bytes)) or not hasattr(value, '__iter__'):
            return f'{spec.name} = {_short(value)} refused: must be a list'
        kind = _kind(default[0]) if len(default) else None
        if kind is not None and not all(kind[1](v) for v in value):
            return f'{spec.name} = {_short(value)} refused: must be a list of {_PLURAL[kind[0]]}'
        return None
    kind = _kind(default)
    if kind is not None and not kind[1](value):
        return f'{spec.name} = {_short(value)} refused: must be {kind[0]}'
    return None


def _short(value, limit: int = 120) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[:limit] + '...'


def check_value(spec: Param, value) -> str | None:
    """The reason `value` is refused for `spec`, or None if it is acceptable."""
    if (reason := type_refusal(spec, value)) is not None:
        return reason
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
