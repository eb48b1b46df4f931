"""YAML files read with errors that name the file and the problem.

Parsed with libyaml's C loader (yaml.CSafeLoader, the same safe subset, ~10x faster on a 10,000-waypoint
mission) where PyYAML was built with it, else with the pure-Python SafeLoader and a note on stderr once.
"""

import os
import re
import sys

import yaml
from yaml.nodes import ScalarNode

try:
    SAFE_LOADER = yaml.CSafeLoader
except AttributeError:  # PyYAML without libyaml
    SAFE_LOADER = yaml.SafeLoader
_noted = []
_FLOAT, _INT, _SEQ = 'tag:yaml.org,2002:float', 'tag:yaml.org,2002:int', 'tag:yaml.org,2002:seq'
# Inputs are bounded: a file larger than this, or one whose aliases expand it to more values than MAX_VALUES
# (a "billion laughs" of nine anchors of nine aliases each is 9^9), is refused before anything walks it. A
# 50,000-waypoint mission is ~1.3 MB and 200,000 values.
MAX_FILE_BYTES = 64 * 2**20
MAX_VALUES = 1_000_000
SHOWN_CHARS = 120   # an echoed value is cut to this many characters


# A plain decimal that YAML 1.1's resolver (float tried before int) tags float when it has a dot, else int.
_DECIMAL = re.compile(r'[-+]?(?:[0-9]+\.[0-9]*(?:[eE][-+][0-9]+)?|0|[1-9][0-9]*)$')
# What YAML 1.1 (PyYAML) leaves a string but a reader takes for a number: 1e9, 2.5e3 (no dot or no exponent sign)
_EXPONENT = re.compile(r'[-+]?[0-9]+(?:\.[0-9]*)?[eE][-+]?[0-9]+$')


class NumbersLoader(SAFE_LOADER):
    """The safe loader with a fast path for numbers, what a long mission is made of: a plain decimal is
    tagged by one regular expression instead of the generic resolver's list of them, and a list of plain
    numbers (a waypoint) is built in one pass instead of ~10 us of construct_object per node. Same values
    and types: what float()/int() cannot read ('0x1f', '1_000', '.inf') goes through the safe constructor."""

    def resolve(self, kind, value, implicit):
        if kind is ScalarNode and implicit[0] and _DECIMAL.match(value):
            return _FLOAT if '.' in value else _INT
        return super().resolve(kind, value, implicit)

    def construct_object(self, node, deep=False):
        if node.tag == _SEQ and node.value:
            out = []
            for c in node.value:
                if c.tag is _FLOAT:
                    out.append(float(c.value))
                elif c.tag is _INT and _DECIMAL.match(c.value):
                    out.append(int(c.value))
                else:
                    break
            else:
                return out
        return super().construct_object(node, deep)


def _note_fallback():
    if SAFE_LOADER is yaml.SafeLoader and not _noted:
        _noted.append(True)
        print('note: PyYAML has no libyaml C loader here; parsing YAML with the slower pure-Python loader',
              file=sys.stderr)


def refuse_number_text(data: dict, keys, where: str):
    """ValueError for a value YAML read as text that was meant as a number (`speed: 1e9` is the string '1e9' to
    YAML 1.1), naming the field and how to write it."""
    for key in keys:
        value = data.get(key)
        if isinstance(value, str) and _EXPONENT.match(value.strip()):
            mantissa, exponent = re.split('[eE]', value.strip())
            sign = '' if exponent[0] in '+-' else '+'
            raise ValueError(f'{where}{key} = {value!r} is text to YAML, not a number: write it with a dot and a '
                             f'signed exponent, e.g. {float(mantissa):.1f}e{sign}{exponent}')


def shown(value, limit: int = SHOWN_CHARS) -> str:
    """repr(value) cut to `limit` characters (an error line names a value, never echoes a whole file)."""
    text = repr(value)
    return text if len(text) <= limit else f'{text[:limit]}... ({len(text):,} characters)'


def as_floats(value, n: int | None = None) -> list[float] | None:
    """The values of a flat list, tuple or 1-D array as floats, as an array of floats would hold them (numeric text
    parsed, None as NaN); None where one is not a number or there are not n of them."""
    value = value.tolist() if hasattr(value, 'tolist') else value
    if not isinstance(value, (list, tuple)) or (n is not None and len(value) != n) \
            or any(isinstance(v, (list, tuple, dict)) for v in value):
        return None
    try:
        return [float('nan') if v is None else float(v) for v in value]
    except (TypeError, ValueError):
        return None


def suggestion(key, known) -> str:
    """' (did you mean 'speed'?)' for a near miss of a known key, else ''."""
    import difflib
    close = difflib.get_close_matches(str(key), [str(k) for k in known], n=1, cutoff=0.6)
    return f' (did you mean {close[0]!r}?)' if close else ''


def refuse_typos(data: dict, known, where: str):
    """ValueError for a top-level key that is not known but nearly is (a typo: `robot_raduis_m`, `mass_kgg`);
    other unknown keys stay the file's own."""
    import difflib
    for key in data:
        if key in known or not isinstance(key, str):
            continue
        close = difflib.get_close_matches(key, list(known), n=1, cutoff=0.8)
        if close:
            raise ValueError(f'{where}: {key} = {data[key]!r} is not a known key (did you mean {close[0]!r}?)')


def load_yaml(path) -> dict:
    path = os.fspath(path)
    try:
        with open(path) as f:
            size = os.fstat(f.fileno()).st_size
            if size > MAX_FILE_BYTES:
                raise ValueError(f'{path}: {size:,} bytes, above the {MAX_FILE_BYTES:,} an input may have')
            _note_fallback()
            data = yaml.load(f, Loader=NumbersLoader)
    except FileNotFoundError:
        raise ValueError(f'{path}: file not found') from None
    except yaml.YAMLError as exc:
        raise ValueError(f'{path}: not valid YAML: {exc}') from None
    except UnicodeDecodeError as exc:
        raise ValueError(f'{path}: not a text (UTF-8) file: byte {exc.start} is '
                         f'0x{exc.object[exc.start]:02x}') from None
    except IsADirectoryError:
        raise ValueError(f'{path}: a directory, not a YAML file') from None
    if not isinstance(data, dict):
        raise ValueError(f'{path}: expected a mapping at the top level, got {type(data).__name__}')
    if _values_above(data, MAX_VALUES):
        raise ValueError(f'{path}: its aliases (*name) expand it to more than {MAX_VALUES:,} values: refused')
    return data


def _values_above(data, limit: int) -> bool:
    """Whether data, with every alias expanded, holds more than `limit` values: a walk that stops at the limit
    (an alias is one shared object, visited again at each of its uses)."""
    count, stack = 0, [data]
    while stack:
        item = stack.pop()
        count += 1
        if count > limit:
            return True
        if isinstance(item, dict):
            stack.extend(item.values())
            count += len(item)
        elif isinstance(item, list):
            stack.extend(v for v in item if isinstance(v, (dict, list)))
            count += len(item)
    return False
