"""User controllers in the offline loop and sweeps (quad_control.plugins through quad_bringup.offline.closed_loop)."""

import json
import os
from pathlib import Path

import pytest

from quad_bringup.experiments import sweep
from quad_bringup.experiments.runs import SpecError
from quad_bringup.offline.closed_loop import LoopOptions, fly_offline
from quad_common.paths import REPO_ROOT, resolve_config

USER_CONTROLLERS = REPO_ROOT / 'src' / 'quad_control' / 'test'
FLIGHTSIM = 'quad_control.templates.flightsim_controller:SE3Control'
WINDOW = resolve_config('config/missions/window.yaml')


@pytest.mark.parametrize('name', ['quad_control.templates.my_controller:MyController',
                                  'quad_control.templates.flightsim_controller:SE3Control'])
def test_the_templates_fly_a_mission_offline(name):
    metrics = fly_offline(WINDOW, LoopOptions(controller=name))
    assert metrics['completed'] and not metrics['collided'] and 'stopped' not in metrics
    assert metrics['rmse_m'] < 0.02


def test_a_user_class_that_raises_stops_the_offline_flight_naming_it(monkeypatch):
    monkeypatch.syspath_prepend(str(USER_CONTROLLERS))
    metrics = fly_offline(WINDOW, LoopOptions(controller='user_controllers:Raises'))
    assert metrics['stopped'].startswith('controller failed at t = ')
    assert 'user_controllers.Raises.update raised ZeroDivisionError' in metrics['stopped']
    assert not metrics['completed']


def test_a_sweep_flies_user_classes_and_records_a_failing_one(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(USER_CONTROLLERS))
    monkeypatch.setenv('PYTHONPATH', f'{USER_CONTROLLERS}:{os.environ.get("PYTHONPATH", "")}')  # the pool's workers
    spec = {'missions': [str(WINDOW)], 'vehicles': ['nominal'], 'disturbances': ['none'], 'seeds': 1,
            'controllers': [{'name': 'flightsim', 'controller': FLIGHTSIM},
                            {'name': 'raises', 'controller': 'user_controllers:Raises'}]}
    (tmp_path / 'spec.yaml').write_text(json.dumps(spec))
    rows, _ = sweep.run_sweep(tmp_path / 'spec.yaml', tmp_path / 'out', figures=False, log=lambda line: None)
    by_name = {r['controller_name']: r for r in rows}
    assert not by_name['flightsim']['failed'] and by_name['flightsim']['rmse_m'] < 0.02
    assert by_name['raises']['failed'] and 'user_controllers.Raises.update raised' in by_name['raises']['failure']


def test_a_sweep_spec_naming_a_class_that_does_not_import_is_refused(tmp_path):
    spec = {'missions': [str(WINDOW)], 'controllers': [{'controller': 'no_such_package.mod:Class'}]}
    (tmp_path / 'spec.yaml').write_text(json.dumps(spec))
    with pytest.raises(SpecError, match="importing 'no_such_package.mod' failed"):
        sweep.expand(sweep.load_spec(tmp_path / 'spec.yaml'))
    assert Path(tmp_path / 'out').exists() is False
