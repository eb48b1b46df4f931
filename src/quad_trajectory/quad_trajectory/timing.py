"""Segment-time allocation: how long each segment of the point list takes.

- sqrt (the seed's speed profile, section 3.1): total time = path length / speed, split across
  segments in proportion to sqrt(segment length): long straight segments fly faster, short ones
  (usually turns) slower.
- proportional: T_i = l_i / speed (constant average speed).
- limits and optimal refine a start allocation with the solver in the loop (planner.py); fastest flies as fast
  as the vehicle's limits less a margin allow (fastest.py).

ALLOCATIONS is what the commands' argument parsers offer, so this module imports nothing heavy at its top: numpy
(and quad_common.types, which imports it) are imported by the functions that use them.
"""

ALLOCATIONS = ('sqrt', 'proportional', 'limits', 'optimal', 'fastest')
# Share of the vehicle's spare thrust the plan may use; the rest is left to the feedback controller.
ACCELERATION_SHARE = 0.5
DEFAULT_V_MAX_MPS = 2.0


def segment_lengths(points):
    import numpy as np

    return np.linalg.norm(np.diff(np.asarray(points, dtype=float)[:, :3], axis=0), axis=1)


def sqrt_allocation(points, speed_mps: float):
    """T_i = (L / v) sqrt(l_i) / sum_j sqrt(l_j)."""
    import numpy as np

    lengths = segment_lengths(points)
    root = np.sqrt(lengths)
    return lengths.sum() / speed_mps * root / root.sum()


def proportional_allocation(points, speed_mps: float):
    return segment_lengths(points) / speed_mps


def vehicle_acceleration_limit(thrust_to_weight: float) -> float:
    """a_max = share * g (TW - 1): the vertical acceleration the spare thrust gives, the binding case."""
    from quad_common.types import GRAVITY_MPS2

    return ACCELERATION_SHARE * GRAVITY_MPS2 * (thrust_to_weight - 1.0)


def vehicle_acceleration_capability(thrust_to_weight: float) -> float:
    """g (TW - 1): no plan may ask for more acceleration than full thrust gives straight up."""
    from quad_common.types import GRAVITY_MPS2

    return GRAVITY_MPS2 * (thrust_to_weight - 1.0)
