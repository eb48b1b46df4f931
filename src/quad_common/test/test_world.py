import json

import numpy as np
import pytest

from quad_common.world import World, load_world

WALL = {'bounds': {'extents': [0, 10, 0, 10, 0, 5]},
        'blocks': [{'extents': [4.0, 4.01, 0, 10, 0, 5], 'color': [1, 0, 0]}]}


def test_distance_to_thin_wall_and_bounds():
    w = World.from_dict(WALL)
    d = w.obstacle_distance([[3.0, 5, 2.5], [4.005, 5, 2.5], [5.0, 5, 2.5], [9.9, 5, 2.5]])
    assert np.allclose(d, [1.0, 0.0, 0.99, 0.1])
    assert w.collides([[3.8, 5, 2.5]], radius_m=0.25).tolist() == [True]
    assert w.collides([[3.7, 5, 2.5]], radius_m=0.25).tolist() == [False]


def test_json_and_yaml_load(tmp_path):
    (tmp_path / 'w.json').write_text(json.dumps(WALL))
    (tmp_path / 'w.yaml').write_text('bounds: {extents: [0, 10, 0, 10, 0, 5]}\nblocks: []\n')
    assert load_world(tmp_path / 'w.json').blocks.shape == (1, 6)
    assert load_world(tmp_path / 'w.yaml').blocks.shape == (0, 6)


@pytest.mark.parametrize('data,words', [
    ({'blocks': []}, 'needs bounds'),
    ({'bounds': {'extents': [0, 1, 0, 1, 0]}}, 'must be 6 finite'),
    ({'bounds': {'extents': [0, 1, 0, 1, 0, 1]}, 'blocks': [{'extents': [2, 1, 0, 1, 0, 1]}]},
     r'blocks\[0\].extents .* max not above'),
])
def test_bad_worlds_are_named(data, words):
    with pytest.raises(ValueError, match=words):
        World.from_dict(data)
