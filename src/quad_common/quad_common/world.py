"""Worlds: axis-aligned boxes inside a bounds volume (the MEAM620 / rotorpy world format).

JSON or YAML, either form:
    {"bounds": {"extents": [xmin, xmax, ymin, ymax, zmin, zmax]},
     "blocks": [{"extents": [xmin, xmax, ymin, ymax, zmin, zmax], "color": [r, g, b]}, ...]}
A robot of radius r collides when its centre is within r of a block or of the bounds' faces.
"""

import json
import os

import numpy as np

from quad_common.yaml_io import load_yaml


def _extents(value, where):
    e = np.asarray(value, dtype=float) if isinstance(value, (list, tuple)) else None
    if e is None or e.shape != (6,) or not np.all(np.isfinite(e)):
        raise ValueError(f'{where} = {value!r} must be 6 finite numbers [xmin, xmax, ymin, ymax, zmin, zmax]')
    if np.any(e[1::2] <= e[0::2]):
        raise ValueError(f'{where} = {value!r} has a max not above its min')
    return e


class World:
    def __init__(self, bounds_extents, block_extents=(), name='world'):
        self.name = name
        self.bounds = _extents(list(bounds_extents), f'{name}: bounds.extents')
        self.blocks = np.array([_extents(list(b), f'{name}: blocks[{i}].extents')
                                for i, b in enumerate(block_extents)]).reshape(-1, 6)

    @classmethod
    def from_dict(cls, data: dict, name='world') -> 'World':
        try:
            bounds = data['bounds']['extents']
        except (KeyError, TypeError):
            raise ValueError(f'{name}: needs bounds: {{extents: [xmin, xmax, ymin, ymax, zmin, zmax]}}') from None
        blocks = data.get('blocks') or []
        if not isinstance(blocks, list) or not all(isinstance(b, dict) and 'extents' in b for b in blocks):
            raise ValueError(f'{name}: blocks must be a list of {{extents: [...]}}')
        return cls(bounds, [b['extents'] for b in blocks], name=name)

    def to_dict(self) -> dict:
        return {'bounds': {'extents': self.bounds.tolist()},
                'blocks': [{'extents': b.tolist()} for b in self.blocks]}

    def obstacle_distance(self, points) -> np.ndarray:
        """Distance (m) from each point (N, 3) to the nearest block surface or bounds face; 0 inside a block."""
        p = np.atleast_2d(np.asarray(points, dtype=float))
        lo_b, hi_b = self.bounds[0::2], self.bounds[1::2]
        d = np.min(np.minimum(p - lo_b, hi_b - p), axis=1).clip(min=0.0)
        if len(self.blocks):
            lo, hi = self.blocks[:, 0::2], self.blocks[:, 1::2]  # (B, 3)
            gap = np.maximum(np.maximum(lo[None] - p[:, None], p[:, None] - hi[None]), 0.0)  # (N, B, 3)
            d = np.minimum(d, np.min(np.linalg.norm(gap, axis=2), axis=1))
        return d

    def collides(self, points, radius_m=0.0) -> np.ndarray:
        """Boolean mask: the sphere of radius_m at each point touches a block or leaves the bounds."""
        return self.obstacle_distance(points) <= radius_m


def load_world(path) -> World:
    """A world from .json (MEAM620 / rotorpy) or .yaml/.yml."""
    path = os.fspath(path)
    if path.endswith('.json'):
        try:
            with open(path) as f:
                data = json.load(f)
        except FileNotFoundError:
            raise ValueError(f'{path}: file not found') from None
        except json.JSONDecodeError as exc:
            raise ValueError(f'{path}: not valid JSON: {exc}') from None
        if not isinstance(data, dict):
            raise ValueError(f'{path}: expected an object at the top level')
    else:
        data = load_yaml(path)
    return World.from_dict(data, name=path)
