"""`quadflight sweep` and `quadflight tune` on a local Dask cluster of 2 worker processes (the same code path as
a cluster of machines: `--scheduler ADDRESS`), and a sweep run through the ROS graph beside its offline twin."""

import csv
import json
import subprocess
from pathlib import Path

import pytest

from quad_bringup.experiments import sweep

ROOT = Path(__file__).resolve().parents[2]
QUADFLIGHT = str(ROOT / 'quadflight')
WINDOW = {'file': 'config/missions/window.yaml', 'speed_mps': 2.0}
FAST = {'name': 'fast', 'profile': 'config/control_fast.yaml'}


@pytest.fixture(scope='module')
def scheduler():
    from dask.distributed import LocalCluster

    with LocalCluster(n_workers=2, processes=True, threads_per_worker=1, dashboard_address=None) as cluster:
        yield cluster.scheduler_address


def quadflight(*args, timeout=300):
    return subprocess.run([QUADFLIGHT, *map(str, args)], capture_output=True, text=True, timeout=timeout)


def test_sweep_on_dask_matches_the_local_pool_and_resumes(tmp_path, scheduler):
    spec = {'missions': [WINDOW, 'config/missions/window.yaml'], 'controllers': ['pd', FAST],
            'disturbances': ['none', {'name': 'wind', 'base': 'drag_wind', 'wind_mps': [1.0, 0.0, 0.0]}],
            'seeds': 1}   # several seeds per configuration: the package tests' sweep (test_sweep.py)
    (tmp_path / 'spec.yaml').write_text(json.dumps(spec))
    out = quadflight('sweep', tmp_path / 'spec.yaml', '--out', tmp_path / 'dask', '--scheduler', scheduler)
    assert out.returncode == 0, out.stderr
    assert 'Dask cluster' in out.stderr and '8 runs' in out.stdout
    dask_rows = {r['key']: r for r in sweep.read_rows(tmp_path / 'dask')}
    local_rows, _ = sweep.run_sweep(tmp_path / 'spec.yaml', tmp_path / 'local', workers=2, figures=False,
                                    log=lambda line: None)
    assert len(dask_rows) == 8 and set(dask_rows) == {r['key'] for r in local_rows}
    for row in local_rows:
        assert dask_rows[row['key']]['rmse_m'] == row['rmse_m'], row['key']
    with open(tmp_path / 'dask' / 'runs.csv') as f:
        assert len(list(csv.DictReader(f))) == 8
    assert (tmp_path / 'dask' / 'figures' / 'rmse_by_controller.png').stat().st_size > 10_000
    summary = (tmp_path / 'dask' / 'summary.md').read_text()
    assert '| window | 2.0 | fast | mission | wind | 1 | 0 |' in summary
    again = quadflight('sweep', tmp_path / 'spec.yaml', '--out', tmp_path / 'dask', '--scheduler', scheduler,
                       '--no-figures')
    assert again.returncode == 0 and len(sweep.read_rows(tmp_path / 'dask')) == 8  # nothing flown twice


def test_tune_on_dask_writes_a_better_profile(tmp_path, scheduler):
    spec = {'controller': {'name': 'soft', 'controller': 'se3', 'gains': {'kp_x': 3.0, 'kp_y': 3.0}},
            'parameters': {'kp_xy': [3.0, 40.0], 'kd_xy': [2.0, 15.0]}, 'missions': [WINDOW],
            'vehicles': [{'name': 'nominal'}, {'name': 'slow', 'plant': {'motor_time_constant_s': 0.03}}],
            'cost': {'aggregate': 'worst'}, 'optimizer': {'maxiter': 2, 'popsize': 3, 'seed': 0}}
    (tmp_path / 'tune.yaml').write_text(json.dumps(spec))
    out = quadflight('tune', tmp_path / 'tune.yaml', '--out', tmp_path / 'out', '--scheduler', scheduler,
                     '--no-verify')
    assert out.returncode == 0, out.stderr
    cost = json.loads((tmp_path / 'out' / 'cost.json').read_text())
    assert cost['cost_after_m'] < 0.8 * cost['cost_before_m'] and cost['evaluations'] >= 1 + 6 * 2
    assert 'worst cost' in out.stdout and (tmp_path / 'out' / 'profile.yaml').exists()
    assert 'Dask cluster' in out.stderr


def test_graph_sweep_flies_fly_and_agrees_with_the_offline_loop(tmp_path):
    """Through the graph with a disturbance the spec defines itself (not in config/disturbances.yaml)."""
    spec = {'missions': [WINDOW], 'controllers': [FAST],
            'disturbances': [{'name': 'wind-1.0', 'base': 'drag', 'wind_mps': [1.0, 0.0, 0.0]}]}   # steady: no gusts
    (tmp_path / 'spec.yaml').write_text(json.dumps(spec))
    out = quadflight('sweep', tmp_path / 'spec.yaml', '--out', tmp_path / 'graph', '--graph', '--no-figures',
                     timeout=400)
    assert out.returncode == 0, out.stderr
    (graph,) = sweep.read_rows(tmp_path / 'graph')
    offline, _ = sweep.run_sweep(tmp_path / 'spec.yaml', tmp_path / 'offline', workers=1, figures=False,
                                 log=lambda line: None)
    assert graph['mode'] == 'graph' and not graph['failed'], graph['failure']
    assert graph['key'] != offline[0]['key']
    assert (tmp_path / 'graph' / 'graph' / graph['key'] / 'flight' / 'bag').is_dir()
    assert graph['disturbance_name'] == 'wind-1.0' and graph['wind_speed_mps'] == pytest.approx(1.0)
    assert graph['rmse_m'] == pytest.approx(offline[0]['rmse_m'], rel=0.1)
    assert graph['time_actual_s'] == pytest.approx(offline[0]['time_actual_s'], abs=0.05)
