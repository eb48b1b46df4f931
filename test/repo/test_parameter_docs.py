"""Each node's parameter table in its docs page lists exactly the node's parameters (SPECS), each with the node's
default and, where the row gives one, its numeric range: the docs are checked both ways against the one source."""

import importlib
import math
import re

import pytest
import yaml

from quad_common.paths import REPO_ROOT

TABLES = [  # (docs page, module holding the node's SPECS)
    ('docs/quad_control.md', 'quad_control.parameters'),
    ('docs/quad_sim.md', 'quad_sim.parameters'),
    ('docs/quad_trajectory.md', 'quad_trajectory.trajectory_node'),
    ('docs/bridge.md', 'quad_bridge.parameters'),
    ('docs/quad_bringup.md', 'quad_bringup.recording.recorder_node'),
]
HEADER = re.compile(r'^\| (name|parameter) \| default \|')
# a default the row words instead of writing it: the words, the name of the module's constant it is (None: '')
WORDED = {'(required)': None, 'the list above': 'DEFAULT_TOPICS'}


def parameter_rows(page: str) -> list[list[str]]:
    """The cells of the rows of the one table in `page` whose header is `| name | default | ...` or
    `| parameter | default | ...`."""
    lines = (REPO_ROOT / page).read_text().splitlines()
    starts = [i for i, line in enumerate(lines) if HEADER.match(line)]
    assert len(starts) == 1, f'{page}: {len(starts)} parameter tables'
    rows = []
    for line in lines[starts[0] + 2:]:
        if not line.startswith('|'):
            break
        rows.append([cell.strip() for cell in line.strip('|').split('|')])
    return rows


def split_top_level(text: str) -> list[str]:
    """`text` split at the commas outside brackets."""
    parts, depth, current = [], 0, ''
    for char in text:
        depth += char == '['
        depth -= char == ']'
        if char == ',' and depth == 0:
            parts.append(current.strip())
            current = ''
        else:
            current += char
    return [*parts, current.strip()]


def literal(text: str):
    """A docs cell's value: backticks and a trailing remark in parentheses dropped, read as YAML (1e-6 as a number)."""
    text = re.sub(r'\s*\(.*\)$', '', text.replace('`', '').strip()) or text.strip()
    value = yaml.safe_load(text)
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            return value
    return value


def same(documented, default) -> bool:
    if isinstance(default, bool) or isinstance(documented, bool):
        return documented is default
    if isinstance(default, (int, float)) and isinstance(documented, (int, float)):
        return math.isclose(documented, default, rel_tol=1e-9, abs_tol=0.0)
    if isinstance(default, (list, tuple)) and isinstance(documented, list):
        return len(documented) == len(default) and all(same(a, b) for a, b in zip(documented, default))
    return documented == default


NUMBER = r'(-?\d+(?:\.\d*)?(?:e[+-]?\d+)?|pi|-pi)'
BOUNDS = re.compile(rf'\[\s*{NUMBER}\s*,\s*{NUMBER}\s*\]|{NUMBER}\s*\.\.\s*{NUMBER}(?![\w^])')


def documented_bounds(cell: str):
    """(min, max) of the first range in a cell written `a .. b`, `a..b` or `[a, b]`, or None."""
    match = BOUNDS.search(cell)
    if not match:
        return None
    low, high = [g for g in match.groups() if g is not None]
    return tuple(math.pi * (-1 if v.startswith('-') else 1) if v.lstrip('-') == 'pi' else float(v) for v in (low, high))


def documented(page: str) -> dict:
    """{parameter name: (documented default, range cell)} of page's table; a row naming several parameters gives
    each its own default (the cell split at top-level commas), or all the same one."""
    out = {}
    for cells in parameter_rows(page):
        names = [name.strip().strip('`') for name in cells[0].split(',')]
        defaults = split_top_level(cells[1])
        if len(defaults) != len(names):
            defaults = [cells[1]] * len(names)
        ranges = split_top_level(cells[2]) if len(cells) > 3 else [''] * len(names)
        if len(ranges) != len(names):
            ranges = [cells[2] if len(cells) > 3 else ''] * len(names)
        for name, default, bounds in zip(names, defaults, ranges):
            assert name not in out, f'{page}: {name} documented twice'
            out[name] = (default, bounds)
    return out


@pytest.mark.parametrize(('page', 'module'), TABLES)
def test_docs_table_lists_exactly_the_nodes_parameters_with_their_defaults(page, module):
    specs = {p.name: p for p in importlib.import_module(module).SPECS}
    rows = documented(page)
    assert not set(specs) - set(rows), f'{page} does not document {sorted(set(specs) - set(rows))}'
    assert not set(rows) - set(specs), f'{page} documents {sorted(set(rows) - set(specs))}: not parameters of ' \
                                       f'{module}'
    for name, (cell, bounds) in rows.items():
        spec = specs[name]
        if cell in WORDED:   # the words stand for the value of the module's constant (None: empty text)
            constant = WORDED[cell]
            worded = list(getattr(importlib.import_module(module), constant)) if constant else ''
            assert same(worded, list(spec.default) if isinstance(spec.default, tuple) else spec.default), name
            continue
        if not isinstance(spec.default, (bool, int, float, str, list, tuple)):   # a typed empty array
            assert literal(cell) == [], f'{page}: {name} documented as {cell!r}, the node\'s default is empty'
            continue
        assert same(literal(cell), spec.default), f'{page}: {name} documented as {cell!r}, the node\'s default is ' \
                                                  f'{spec.default!r}'
        pair = documented_bounds(bounds)
        if pair is not None and spec.min is not None and spec.max is not None:
            assert pair == pytest.approx((spec.min, spec.max)), f'{page}: {name} range {bounds!r}, the node\'s is ' \
                                                                f'{spec.min}..{spec.max}'


def test_a_wrong_default_or_a_missing_row_is_caught():
    """The check itself: a row with another default, or a parameter left out, is seen."""
    from quad_control.parameters import SPECS
    specs = {p.name: p for p in SPECS}
    rows = documented('docs/quad_control.md')
    assert not same(literal('6, 5, 20'.split(', ')[0]), specs['kp_x'].default)
    assert same(literal(rows['kp_x'][0]), specs['kp_x'].default)
    assert set(specs) - (set(rows) - {'kp_y'}) == {'kp_y'}
    assert documented_bounds('0.001 .. 10') == (0.001, 10.0) and documented_bounds('[1e-4, 1], whole') == (1e-4, 1.0)
