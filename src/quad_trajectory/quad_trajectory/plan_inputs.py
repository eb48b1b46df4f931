"""A plan's inputs checked in pure Python (floats, math.isfinite; no numpy): the waypoints, the yaw and the values of
PlanOptions, so a command refuses a bad mission before numpy is imported. quad_trajectory.planner builds its arrays
from what these return and checks what needs the vehicle or user code. Errors name the field and the value."""

import math
import numbers
from dataclasses import dataclass

from quad_common.yaml_io import as_floats, shown
from quad_trajectory import timing

ORDERS = {'minaccel': 2, 'minjerk': 3, 'minsnap': 4}   # method -> the derivative whose integral square is minimised
MODES = ('continuity', 'stop')                         # waypoint_constraint
DEFAULT_MARGIN = 0.1                                   # fastest: the fraction of each vehicle limit left unused


@dataclass
class PlanOptions:
    method: str = 'minsnap'                    # minaccel | minjerk | minsnap
    waypoint_constraint: str = 'continuity'    # continuity | stop
    speed_mps: float = 0.5                     # the seed's speed constant
    time_allocation: str = 'sqrt'              # sqrt | proportional | limits | optimal | fastest
    control_points: tuple = ()                 # fractions along each segment, the seed's (0.1, 0.9)
    v_max_mps: float | None = None             # limits; None: timing.DEFAULT_V_MAX_MPS
    a_max_mps2: float | None = None            # limits; None: from the vehicle's thrust-to-weight
    rho: float | None = None                   # optimal: weight of total time; None: 2r - 1
    margin: float = DEFAULT_MARGIN             # fastest: the fraction of each vehicle limit left unused
    robot_radius_m: float = 0.0
    avoid_collisions: bool = True              # insert points and replan until collision-free
    generator: str = ''                        # a user's trajectory class, package.module:Class (generated.py)
    generator_args: dict | None = None         # its keyword arguments after the waypoints
    generator_waypoints: bool = True           # False: built from generator_args alone (a circle, a Lissajous)
    duration_s: float | None = None            # how long it is sampled; None: the instance's duration_s


def finite_number(name, value, positive=True) -> float:
    ok = isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value) and \
        (value > 0 if positive else value >= 0)
    if not ok:
        raise ValueError(f'{name} = {value!r} must be a finite number {"> 0" if positive else ">= 0"}')
    return float(value)


def waypoint_rows(waypoints) -> list[list[float]]:
    """The waypoints as [x, y, z] floats (at least two, all finite); ValueError naming the first bad one by its index
    (never the whole list: 50,000 of them are 1 MB)."""
    listed = waypoints.tolist() if hasattr(waypoints, 'tolist') else waypoints
    rows = [as_floats(point, 3) for point in listed] if isinstance(listed, (list, tuple)) else None
    if not rows or None in rows:
        if isinstance(waypoints, (list, tuple)):
            bad = next((i for i, row in enumerate(rows) if row is None), None)
            if bad is not None:
                raise ValueError(f'waypoints[{bad}] = {shown(waypoints[bad])} must be [x, y, z] in metres (numbers)')
        raise ValueError(f'waypoints = {shown(waypoints)} must be a list of [x, y, z] in metres')
    for i, row in enumerate(rows):
        if not all(math.isfinite(v) for v in row):
            raise ValueError(f'waypoints[{i}] = {row} must be finite')
    if len(rows) < 2:
        raise ValueError(f'waypoints = {rows} needs at least two distinct waypoints')
    return rows


def yaw_values(yaw, n: int) -> float | list[float] | None:
    """None (0), one number, or n numbers, all finite; ValueError naming the yaw otherwise."""
    if yaw is None:
        return None
    if isinstance(yaw, numbers.Real):
        values = float(yaw)
    else:
        values = as_floats(yaw, n) if not isinstance(yaw, str) else None
        if values is None:
            raise ValueError(f'yaw = {yaw!r} must be one number or one per waypoint ({n})')
    if not all(math.isfinite(v) for v in (values if isinstance(values, list) else [values])):
        raise ValueError(f'yaw = {yaw!r} must be finite')
    return values


def check_option_values(o: PlanOptions) -> PlanOptions:
    """Each option's own rule (planner.validate_options adds what needs the vehicle and resolves a generator)."""
    if o.method not in ORDERS:
        raise ValueError(f'method = {o.method!r} must be one of {", ".join(ORDERS)}')
    if o.waypoint_constraint not in MODES:
        raise ValueError(f'waypoint_constraint = {o.waypoint_constraint!r} must be one of {", ".join(MODES)}')
    if o.time_allocation not in timing.ALLOCATIONS:
        raise ValueError(f'time_allocation = {o.time_allocation!r} must be one of {", ".join(timing.ALLOCATIONS)}')
    finite_number('speed', o.speed_mps)
    finite_number('robot_radius_m', o.robot_radius_m, positive=False)
    fractions = tuple(o.control_points or ())
    for f in fractions:
        if not (isinstance(f, (int, float)) and 0 < f < 1):
            raise ValueError(f'control_points = {list(fractions)!r} must be fractions strictly between 0 and 1')
    if o.v_max_mps is not None:
        finite_number('limits.v_max_mps', o.v_max_mps)
    if o.a_max_mps2 is not None:
        finite_number('limits.a_max_mps2', o.a_max_mps2)
    if o.rho is not None:
        finite_number('rho', o.rho)
    if not (isinstance(o.margin, (int, float)) and not isinstance(o.margin, bool) and 0.0 <= o.margin < 1.0):
        raise ValueError(f'margin = {o.margin!r} must be a fraction in [0, 1) (0.1: 10 % of each limit unused)')
    return o
