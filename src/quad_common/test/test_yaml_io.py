"""load_yaml: libyaml's C loader with a fast path for numbers, giving exactly what yaml.safe_load gives."""

import pytest
import yaml

from quad_common import yaml_io
from quad_common.yaml_io import load_yaml

TRICKY = """
numbers: [0x1f, 1_000, .inf, -.inf, 1.5, -2, +3, 1e3, 1.5e+3, 017, 0, 1:30, 1., '2.5', 0.0, -0.0, .5]
mixed: [1.0, two, 3, null, true]
nested: [[0.1, 0.2, 0.3], [1, 2, 3]]
plain: 1.25
word: yes
date: 2001-12-14
"""


def test_numbers_fast_path_gives_what_safe_load_gives(tmp_path):
    path = tmp_path / 'tricky.yaml'
    path.write_text(TRICKY)
    got, want = load_yaml(path), yaml.safe_load(TRICKY)
    assert got == want
    for a, b in zip(got['numbers'], want['numbers']):
        assert type(a) is type(b) and repr(a) == repr(b)   # 1e3 stays a string, 017 an octal int, -0.0 signed


def test_the_c_loader_is_used_where_pyyaml_has_it():
    assert yaml_io.SAFE_LOADER is getattr(yaml, 'CSafeLoader', yaml.SafeLoader)


def test_bad_yaml_is_named(tmp_path):
    path = tmp_path / 'bad.yaml'
    path.write_text('a: [1, 2\n')
    with pytest.raises(ValueError, match='bad.yaml: not valid YAML'):
        load_yaml(path)
