"""A user's trajectory class as a mission's plan (quad_trajectory.generated): sampled and fitted exactly, checked
against the vehicle like our plans, and refused with one line naming the class, t and the field when it fails."""

import sys
import textwrap

import numpy as np
import pytest

from quad_common.paths import resolve_config
from quad_trajectory.mission import load_mission, plan_mission, preflight
from quad_trajectory.templates.circle import Circle

CRAZYFLIE = resolve_config('config/vehicles/crazyflie.yaml').resolve()
CIRCLE = 'quad_trajectory.templates.circle:Circle'


def _mission(tmp_path, trajectory: str, waypoints='[[0, 0, 1], [1, 0, 1]]'):
    path = tmp_path / 'gen.yaml'
    path.write_text(f'name: gen\nvehicle: {CRAZYFLIE}\nwaypoints: {waypoints}\ntrajectory:\n'
                    + textwrap.indent(textwrap.dedent(trajectory), '  '))
    return load_mission(path)


def test_the_plan_is_the_class_sampled_and_fitted_through_its_samples(tmp_path):
    mission = _mission(tmp_path, f'generator: {CIRCLE}\ngenerator_args: {{radius_m: 0.5, period_s: 6.0}}\n')
    result = plan_mission(mission)
    traj = result.trajectory
    assert traj.duration_s == pytest.approx(6.0) and traj.n_segments == 600
    circle = Circle(mission.waypoints, radius_m=0.5, period_s=6.0)
    for t in (0.0, 1.234, 3.0, 4.995, 6.0):                    # between samples too: the quintic is that close
        flat = circle.update(t)
        assert np.allclose(traj.evaluate(t, 0)[:3], flat['x'], atol=1e-7)
        assert np.allclose(traj.evaluate(t, 1)[:3], flat['x_dot'], atol=1e-5)
        assert np.allclose(traj.evaluate(t, 2)[:3], flat['x_ddot'], atol=1e-3)
    assert np.allclose(result.waypoints, [[0, 0, 1], [0, 0, 1]], atol=1e-12)   # its own start and end
    assert result.waypoint_times_s().tolist() == [0.0, pytest.approx(6.0)]
    report = preflight(mission, result)                        # the feasibility check runs on it as on ours
    assert report.ok, report.lines()


def test_a_plan_the_vehicle_cannot_fly_is_refused_by_the_feasibility_check(tmp_path):
    mission = _mission(tmp_path, f'generator: {CIRCLE}\ngenerator_args: {{radius_m: 3.0, period_s: 2.0}}\n')
    report = preflight(mission, plan_mission(mission))
    assert not report.ok and 'tilt' in '\n'.join(report.lines())


def test_the_mission_s_duration_overrides_the_class_s(tmp_path):
    mission = _mission(tmp_path, f'generator: {CIRCLE}\nduration_s: 4.0\n')
    assert plan_mission(mission).trajectory.duration_s == pytest.approx(4.0)


BROKEN = '''
import math
class NoDuration:
    def __init__(self, waypoints):
        pass
    def update(self, t):
        return {}
class NaNAt:
    duration_s = 2.0
    def __init__(self, waypoints):
        pass
    def update(self, t):
        bad = t > 1.0
        return {'x': [0.0, 0.0, math.nan if bad else 1.0], 'x_dot': [0, 0, 0], 'x_ddot': [0, 0, 0], 'yaw': 0.0}
class NoVelocity(NaNAt):
    def update(self, t):
        return {'x': [0.0, 0.0, 1.0], 'x_ddot': [0, 0, 0], 'yaw': 0.0}
class Raises(NaNAt):
    def update(self, t):
        raise RuntimeError('no plan here')
class BadInit:
    def __init__(self, waypoints, speed):
        pass
    def update(self, t):
        return {}
'''


@pytest.mark.parametrize('cls, says', [
    ('NoDuration', "its duration is unknown (None): set trajectory.duration_s"),
    ('NaNAt', "broken_gen:NaNAt.update(1.010)['x'] = [0.0, 0.0, nan] is not 3 finite numbers"),
    ('NoVelocity', "broken_gen:NoVelocity.update(0.000) has no 'x_dot'"),
    ('Raises', 'broken_gen:Raises.update(0.000) raised RuntimeError: no plan here'),
    ('BadInit', "building it failed: TypeError"),
])
def test_a_class_that_fails_is_refused_naming_it(tmp_path, monkeypatch, cls, says):
    (tmp_path / 'broken_gen.py').write_text(BROKEN)
    monkeypatch.syspath_prepend(str(tmp_path))
    mission = _mission(tmp_path, f'generator: broken_gen:{cls}\n')
    with pytest.raises(ValueError, match='.*') as refused:
        plan_mission(mission)
    assert says in str(refused.value) and str(mission.path) in str(refused.value)
    sys.modules.pop('broken_gen', None)


def test_a_generator_that_does_not_import_is_refused_when_the_mission_loads(tmp_path):
    with pytest.raises(ValueError, match="trajectory.generator = 'nope.mod:X': importing 'nope.mod' failed"):
        _mission(tmp_path, 'generator: nope.mod:X\n')
    with pytest.raises(ValueError, match='generator_args = 3 must be a mapping'):
        _mission(tmp_path, f'generator: {CIRCLE}\ngenerator_args: 3\n')
