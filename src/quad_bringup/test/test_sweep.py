"""quadflight sweep / tune cores: spec expansion and its refusals, run keys, resume after an interrupt, rows that
fly again to the same numbers, plant-only overrides, the robust cost, and a tune that beats its start."""

import json

import numpy as np
import pytest

from quad_bringup.experiments import runs, sweep, tune
from quad_bringup.pools.executors import LocalExecutor
from quad_control.parameters import profile_parameters

WINDOW = {'file': 'config/missions/window.yaml', 'speed_mps': 2.0}
SPEC = {'missions': [WINDOW], 'controllers': ['pd', {'name': 'fast', 'profile': 'config/control_fast.yaml'}],
        'vehicles': [{'name': 'nominal'}, {'name': 'slow', 'plant': {'motor_time_constant_s': 0.03}}],
        'disturbances': ['none', {'name': 'wind', 'base': 'drag', 'wind_mps': [1.0, 0.0, 0.0]}], 'seeds': 2}


class SerialExecutor:
    """The executor interface in this process (results in order); `stop_after` raises KeyboardInterrupt then."""

    description = 'serial'

    def __init__(self, stop_after=None):
        self.stop_after, self.calls = stop_after, 0

    def map_unordered(self, fn, items, *args):
        for i, item in enumerate(items):
            if self.stop_after is not None and self.calls >= self.stop_after:
                raise KeyboardInterrupt
            self.calls += 1
            yield i, fn(item, *args)

    def close(self):
        pass


def test_grid_is_the_product_of_the_axes_and_random_samples_it_reproducibly():
    grid = sweep.expand(SPEC)
    assert len(grid) == 1 * 2 * 2 * 2 * 2
    assert len({runs.run_key(p) for p in grid}) == len(grid)
    assert {p['controller_name'] for p in grid} == {'pd', 'fast'}
    fast = next(p for p in grid if p['controller_name'] == 'fast')
    assert fast['gains']['controller'] == 'se3' and fast['gains']['kp_x'] == 25.0
    assert next(p for p in grid if p['disturbance_name'] == 'wind')['disturbances'] == {
        'body_drag': True, 'rotor_drag': True, 'wind_mps': [1.0, 0.0, 0.0]}
    a = sweep.expand({**SPEC, 'sample': 'random', 'samples': 5, 'seed': 3})
    b = sweep.expand({**SPEC, 'sample': 'random', 'samples': 5, 'seed': 3})
    c = sweep.expand({**SPEC, 'sample': 'random', 'samples': 5, 'seed': 4})
    assert len(a) == 5 and [runs.run_key(p) for p in a] == [runs.run_key(p) for p in b]
    assert [runs.run_key(p) for p in a] != [runs.run_key(p) for p in c]


@pytest.mark.parametrize('change, message', [
    ({'colour': 1}, "unknown key.*colour"),
    ({'controllers': [{'controller': 'se3', 'gains': {'kp_x': -1.0}}]}, 'kp_x = -1.0 refused'),
    ({'controllers': [{'controller': 'lqr'}]}, "controller = 'lqr' refused"),
    ({'controllers': [{'gains': {'kp_w': 1.0}}]}, "unknown controller key 'kp_w'"),
    ({'vehicles': [{'plant': {'motor_time_constant_s': -0.03}}]}, 'motor_time_constant_s = -0.03'),
    ({'vehicles': [{'plant': {'mass_kg': 0.03}}]}, "plant sets \\['mass_kg'\\]"),
    ({'vehicles': ['no_such_member']}, 'no_such_member'),
    ({'disturbances': [{'base': 'hurricane'}]}, "base = 'hurricane'"),
    ({'disturbances': [{'name': 'w', 'wind_mps': [1.0, 0.0]}]}, 'wind_mps'),
    ({'missions': ['config/missions/nowhere.yaml']}, 'nowhere.yaml'),
    ({'missions': [{'file': 'config/missions/window.yaml', 'speed_mps': 0}]}, 'speed_mps = 0'),
    ({'missions': [{'file': 'config/missions/window.yaml', 'time_allocation': 'fastests'}]},
     "time_allocation = 'fastests' must be one of .*fastest"),
    ({'seeds': 0}, 'seeds = 0'),
    ({'sample': 'random'}, 'samples = None'),
    ({'controllers': ['pd', 'pd']}, 'names must differ'),
])
def test_bad_spec_refused_naming_the_field_and_value(change, message):
    with pytest.raises(runs.SpecError, match=message):
        sweep.expand({**SPEC, **change})


def test_a_spec_flies_fastest_offline_and_records_it(tmp_path):
    spec = {**SPEC, 'missions': [{'file': 'config/missions/window.yaml', 'time_allocation': 'fastest'}],
            'controllers': ['se3'], 'vehicles': [{'name': 'nominal'}], 'disturbances': ['none'], 'seeds': 1}
    grid = sweep.expand(spec)
    assert [p['time_allocation'] for p in grid] == ['fastest']
    row = runs.run_one(grid[0])
    from quad_common.paths import resolve_config
    from quad_trajectory.mission import load_mission, plan_mission
    planned = plan_mission(load_mission(resolve_config('config/missions/window.yaml')), time_allocation='fastest')
    assert row['params']['time_allocation'] == 'fastest' and not row['failed']
    assert row['time_planned_s'] == pytest.approx(planned.trajectory.duration_s, abs=0.02)


def test_the_key_covers_every_parameter():
    params = sweep.expand(SPEC)[0]
    key = runs.run_key(params)
    assert runs.run_key(json.loads(json.dumps(params))) == key  # survives the table's JSON
    for change in ({'seed': 7}, {'speed_mps': 1.0}, {'plant': {'mass_error': 0.1}}, {'mode': 'graph'},
                   {'gains': {**params['gains'], 'kd_z': 11.0}}, {'options': {**params['options'], 'rate_hz': 200}},
                   {'mission_sha': '0' * 16}):
        assert runs.run_key({**params, **change}) != key, change


def test_interrupted_sweep_keeps_finished_rows_and_resumes_only_the_rest(tmp_path):
    params = sweep.expand({**SPEC, 'controllers': ['pd'], 'vehicles': [None], 'seeds': 1})  # 2 runs
    table = sweep.RunTable(tmp_path)
    with pytest.raises(KeyboardInterrupt):
        sweep.execute(params, table, SerialExecutor(stop_after=1), 'test')
    table.close()
    assert len(sweep.read_rows(tmp_path)) == 1
    with open(tmp_path / 'runs.jsonl', 'a') as f:
        f.write('{"key": "cut sho')  # a row cut short by a kill: flown again, not fatal
    table = sweep.RunTable(tmp_path)
    executor = SerialExecutor()
    rows = sweep.execute(params, table, executor, 'test')
    table.close()
    assert executor.calls == 1 and [r['key'] for r in rows] == [runs.run_key(p) for p in params]
    csv_lines = (tmp_path / 'runs.csv').read_text().splitlines()
    assert csv_lines[0].startswith('key,mode,mission') and len(csv_lines) == 3


def test_a_row_flies_again_to_the_same_numbers_and_names_its_versions():
    params = next(p for p in sweep.expand(SPEC) if p['disturbance_name'] == 'wind' and p['seed'] == 1
                  and p['controller_name'] == 'fast')
    row = runs.run_one(params)
    again = runs.run_one(json.loads(json.dumps(row['params'])))
    assert row['rmse_m'] == again['rmse_m'] and row['time_actual_s'] == again['time_actual_s']
    assert row['versions']['numpy'] == np.__version__ and row['git_commit']
    assert not row['failed'] and row['time_planned_s'] > 0 and row['length_actual_m'] > 0
    assert row['avg_velocity_mps'] > 1.5 and row['wind_speed_mps'] == 1.0


def test_plant_overrides_change_the_plant():
    base = next(p for p in sweep.expand(SPEC) if p['controller_name'] == 'fast' and p['vehicle_name'] == 'nominal'
                and p['disturbance_name'] == 'none' and p['seed'] == 0)
    nominal = runs.run_one(base)
    lagged = runs.run_one({**base, 'plant': {'motor_time_constant_s': 0.05}})  # 15 ms nominal
    assert not lagged['failed'] and lagged['rmse_m'] > nominal['rmse_m'] * 1.02
    assert runs.run_one({**base, 'plant': {}})['rmse_m'] == nominal['rmse_m']
    heavy = runs.run_one({**base, 'plant': {'mass_error': 0.2}})  # the controller still believes the file's mass
    assert heavy['rmse_m'] > nominal['rmse_m'] * 1.5


def test_the_plant_family_by_name():
    grid = sweep.expand({**SPEC, 'vehicles': 'plant_family', 'controllers': ['pd'], 'disturbances': ['none'],
                         'seeds': 1})
    names = [p['vehicle_name'] for p in grid]
    assert 'nominal' in names and 'heavy_20pct' in names and len(names) >= 5
    heavy = next(p for p in grid if p['vehicle_name'] == 'heavy_20pct')
    assert heavy['plant'] == {'mass_error': 0.2}
    (member,) = sweep.expand({**SPEC, 'vehicles': ['autopilot_so3'], 'controllers': ['pd'],
                              'disturbances': ['none'], 'seeds': 1})
    assert member['plant']['attitude_loop']['type'] == 'so3_pd'


def test_failed_and_raising_runs_are_rows_not_losses():
    base = sweep.expand(SPEC)[0]
    crashed = runs.run_one({**base, 'plant': {'motor_time_constant_s': 0.2}})  # attitude loop rings, diverges
    assert crashed['failed'] and crashed['failure']
    broken = runs.run_one({**base, 'mission': 'config/missions/gone.yaml'})
    assert broken['failed'] and 'gone.yaml' in broken['failure'] and broken['rmse_m'] is None


def test_summary_statistics_per_configuration():
    rows = [{'mission': 'm', 'speed_mps': None, 'controller_name': 'c', 'vehicle_name': 'v',
             'disturbance_name': 'd', 'rmse_m': r, 'max_error_m': 2 * r if r else None, 'time_over_s': 0.1,
             'failed': r is None} for r in (0.01, 0.02, 0.03, 0.04, None)]
    (s,) = sweep.summarize(rows)
    assert s['runs'] == 5 and s['failures'] == 1
    assert s['rmse_median_m'] == pytest.approx(0.025) and s['rmse_worst_m'] == 0.04
    assert s['rmse_p95_m'] == pytest.approx(np.percentile([0.01, 0.02, 0.03, 0.04], 95))


def test_run_cost_penalises_failure_tilt_and_saturation():
    cost = tune.COST_DEFAULTS
    ok = {'failed': False, 'rmse_m': 0.01, 'max_tilt_deg': 20.0, 'saturated_fraction': 0.0}
    assert tune.run_cost(ok, cost) == pytest.approx(0.01)
    assert tune.run_cost({**ok, 'max_tilt_deg': 40.0}, cost) == pytest.approx(0.01 + 0.01 * 10)
    assert tune.run_cost({**ok, 'saturated_fraction': 0.5}, cost) == pytest.approx(0.01 + 0.05)
    assert tune.run_cost({**ok, 'failed': True}, cost) == cost['divergence_m']


def test_tune_beats_a_poor_start_and_writes_profile_and_tables(tmp_path):
    spec = {'controller': {'name': 'soft', 'controller': 'se3', 'gains': {'kp_x': 3.0, 'kp_y': 3.0}},
            'parameters': {'kp_xy': [3.0, 40.0]}, 'missions': [WINDOW],
            'vehicles': [{'name': 'nominal'}, {'name': 'slow', 'plant': {'motor_time_constant_s': 0.03}}],
            'optimizer': {'maxiter': 1, 'popsize': 3, 'seed': 1}, 'verify': False}
    (tmp_path / 'spec.yaml').write_text(json.dumps(spec))
    summary = tune.run_tune(tmp_path / 'spec.yaml', tmp_path / 'out', workers=2, log=lambda line: None)
    assert summary['cost_after_m'] < 0.8 * summary['cost_before_m']
    assert summary['best_gains']['kp_x'] == summary['best_gains']['kp_y'] > 3.0
    profile = profile_parameters(runs.load_yaml(tmp_path / 'out' / 'profile.yaml'))
    assert profile['kp_x'] == summary['best_gains']['kp_x'] and profile['controller'] == 'se3'
    evaluations = (tmp_path / 'out' / 'evaluations.csv').read_text().splitlines()
    assert evaluations[0].startswith('evaluation,generation,kp_xy,cost') and len(evaluations) >= 1 + 1 + 3
    assert len(sweep.read_rows(tmp_path / 'out')) >= 2 * 3


def test_tune_refuses_bounds_without_the_start():
    with pytest.raises(runs.SpecError, match="kp_xy.*must contain the starting profile's kp_x = 25.0"):
        tune.Tuning({'controller': {'profile': 'config/control_fast.yaml'}, 'parameters': {'kp_xy': [1, 10]},
                     'missions': [WINDOW]}, None, None)


def test_local_pool_gives_the_serial_numbers(tmp_path):
    params = sweep.expand({**SPEC, 'controllers': ['pd'], 'seeds': 1})
    serial = {p['seed']: runs.run_one(p)['rmse_m'] for p in params[:1]}
    pool = LocalExecutor(2)
    try:
        results = dict(pool.map_unordered(runs.run_one, params[:2]))
    finally:
        pool.close()
    assert results[0]['rmse_m'] == serial[0] and results[1]['key'] == runs.run_key(params[1])


FORMATION = {'file': 'config/missions/fleets/formation4.yaml', 'speed_mps': 1.5}
CROSSING = 'config/missions/fleets/crossing2.yaml'


def test_a_sweep_flies_fleet_missions_beside_single_ones(tmp_path, monkeypatch):
    monkeypatch.setattr('quad_bringup.pools.executors.make_executor', lambda scheduler, workers: SerialExecutor())
    spec = {'missions': [FORMATION, WINDOW], 'seeds': 1,
            'controllers': ['pd', {'name': 'fast', 'profile': 'config/control_fast.yaml'}]}
    (tmp_path / 'spec.yaml').write_text(json.dumps(spec))
    rows, summary = sweep.run_sweep(tmp_path / 'spec.yaml', tmp_path / 'out', log=lambda line: None)
    assert len(rows) == 4 and not any(r['failed'] for r in rows), [r['failure'] for r in rows]
    fleet = {r['controller_name']: r for r in rows if r['mission'] == 'formation4'}
    assert set(fleet) == {'pd', 'fast'}
    for name, row in fleet.items():
        vehicles = row['vehicles']
        assert list(vehicles) == ['cf1', 'cf2', 'cf3', 'cf4'] and row['fleet_size'] == 4
        assert row['completed'] and row['collided'] is False and row['vehicle_collisions'] == 0
        assert row['rmse_m'] == max(v['rmse_m'] for v in vehicles.values())
        assert row['max_error_m'] == max(v['max_error_m'] for v in vehicles.values())
        assert 0.3 < row['min_separation_m'] < 0.9 and row['planned_separation_m'] == pytest.approx(0.8)
        flown = {'pd': 'pd', 'fast': 'se3'}[name]   # the point's controller; cf4 names its own (pid) and keeps it
        assert [v['controller'] for v in vehicles.values()] == [flown, flown, flown, 'pid']
    assert fleet['pd']['vehicles']['cf1']['rmse_m'] != fleet['fast']['vehicles']['cf1']['rmse_m']  # the gains flew
    saturated = [v['saturated_fraction'] for v in fleet['pd']['vehicles'].values()]
    assert 0 < fleet['pd']['saturated_fraction'] == max(saturated)
    single = [r for r in rows if r['mission'] == 'window']
    assert all(r['fleet_size'] is None and r['vehicles'] is None for r in single)
    stored = {r['key']: r for r in sweep.read_rows(tmp_path / 'out')}
    assert stored[fleet['fast']['key']]['vehicles'] == fleet['fast']['vehicles']
    assert {(s['mission'], s['controller_name']): (s['vehicles'], s['min_separation_m']) for s in summary} == {
        **{('formation4', n): (4, r['min_separation_m']) for n, r in fleet.items()},
        ('window', 'pd'): (None, None), ('window', 'fast'): (None, None)}
    assert 'min_separation_m' in (tmp_path / 'out' / 'summary.md').read_text()
    assert (tmp_path / 'out' / 'figures' / 'rmse_by_controller.png').stat().st_size > 0
    header = (tmp_path / 'out' / 'runs.csv').read_text().splitlines()[0].split(',')
    assert {'fleet_size', 'vehicle_collisions', 'min_separation_m', 'vehicles'} <= set(header)
    # the point's gains, plant and wind reach every vehicle of the fleet
    base, pd = json.loads(json.dumps(fleet['pd']['params'])), fleet['pd']['vehicles']
    soft = {**base['gains'], **{f'kp_{a}': base['gains'][f'kp_{a}'] / 3 for a in 'xyz'}}
    soft = runs.run_one({**base, 'gains': soft})   # (deterministic: 1.07x for cf1-3, 1.14x for cf4)
    assert all(soft['vehicles'][n]['rmse_m'] > 1.04 * pd[n]['rmse_m'] for n in pd)
    heavy = runs.run_one({**base, 'plant': {'mass_error': 0.2}})   # the controllers believe the file's mass
    assert all(heavy['vehicles'][n]['rmse_m'] > 1.2 * pd[n]['rmse_m'] for n in pd)
    windy = runs.run_one({**base, 'disturbance_name': 'wind', 'disturbances': {'wind_mps': [1.5, 0.0, 0.0],
                                                                                'body_drag': True}})
    assert all(windy['vehicles'][n]['final_error_m'] > 10 * pd[n]['final_error_m'] for n in ('cf1', 'cf2', 'cf3'))
    assert windy['failed'] and windy['failure'] == 'not completed within the time limit: cf1, cf2, cf3'  # pd: no ki


def test_a_fleet_conflict_is_a_failed_row_naming_the_pair_and_graph_refuses_fleets():
    spec = {'missions': [CROSSING], 'controllers': ['pd'], 'seeds': 1}
    (params,) = sweep.expand(spec)
    row = runs.run_one(params)
    assert row['failed'] and row['failure'].startswith('separation conflict: cf1 and cf2 come 0.000 m apart')
    assert row['fleet_size'] == 2 and row['rmse_m'] is None and set(row['vehicles']) == {'cf1', 'cf2'}
    (s,) = sweep.summarize([row])
    assert s['failures'] == 1 and s['min_separation_m'] is None and s['vehicle_collisions'] is None  # not flown
    with pytest.raises(runs.SpecError, match=r'missions\[1\]: .*crossing2.yaml is a fleet mission.*drop --graph'):
        sweep.expand({**spec, 'missions': [WINDOW, CROSSING]}, mode='graph')


def test_the_sweep_examples_failures_are_the_ones_the_readme_explains(tmp_path):
    """controllers_wind.yaml's pd fails on the 20 % heavier vehicle (no integral: it never comes within the
    completion tolerance) where se3-fast completes: the README says a quarter of its runs fail for this."""
    from quad_common.paths import REPO_ROOT
    from quad_common.yaml_io import load_yaml

    example = load_yaml(REPO_ROOT / 'config/experiments/controllers_wind.yaml')
    spec = {'missions': ['config/missions/window.yaml'],
            'controllers': [c for c in example['controllers']
                            if c == 'pd' or isinstance(c, dict) and c['name'] == 'se3-fast'],
            'vehicles': ['heavy_20pct'], 'disturbances': ['none'], 'seeds': 1}
    (tmp_path / 'spec.yaml').write_text(json.dumps(spec))
    rows, _ = sweep.run_sweep(tmp_path / 'spec.yaml', tmp_path / 'out', workers=1, figures=False,
                              log=lambda line: None)
    verdicts = {r['controller_name']: r['failure'] if r['failed'] else 'completed' for r in rows}
    assert verdicts == {'pd': 'not completed within the time limit', 'se3-fast': 'completed'}
    assert '324 runs, 81 failed' in (REPO_ROOT / 'README.md').read_text().replace('\n', ' ')
