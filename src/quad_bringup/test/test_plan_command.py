"""`quadflight plan`: the plan JSON layout of docs/design.md, the CSV samples, the summary, and bad input."""

import json
import os

import numpy as np
import pytest

from quad_bringup.cli import main
from quad_trajectory.mission import DEFAULT_MISSION_PATH
from quad_trajectory.polynomial import PiecewisePolynomial


def test_plan_writes_json_and_csv_and_prints_a_summary(tmp_path, capsys):
    out = tmp_path / 'plans' / 'traj.json'
    assert main(['plan', DEFAULT_MISSION_PATH, '--out', str(out), '--csv', '50']) == 0
    printed = capsys.readouterr().out
    for words in ('segments', 'time planned (s)', 'length planned (m)', 'max speed (m/s)'):
        assert words in printed
    data = json.loads(out.read_text())
    assert np.asarray(data['waypoints']).shape[1] == 3
    seg = data['segments'][0]
    assert set(seg['coefficients']) == {'x', 'y', 'z', 'yaw'} and len(seg['coefficients']['x']) == 8
    traj = PiecewisePolynomial.from_dict(data)
    np.testing.assert_allclose(traj.evaluate(0.0)[:3], data['waypoints'][0], atol=1e-12)
    np.testing.assert_allclose(traj.evaluate(traj.duration_s)[:3], data['waypoints'][-1], atol=1e-9)
    assert data['summary']['time_planned_s'] == pytest.approx(traj.duration_s)
    csv = np.loadtxt(out.with_suffix('.csv'), delimiter=',', skiprows=1)
    assert csv.shape[1] == 13
    assert csv[1, 0] == pytest.approx(0.02) and csv[-1, 0] == pytest.approx(traj.duration_s)
    np.testing.assert_allclose(csv[:, 1:5], traj.evaluate(csv[:, 0]), atol=1e-8)


def test_speed_override_shortens_the_plan(tmp_path):
    slow, fast = tmp_path / 'slow.json', tmp_path / 'fast.json'
    assert main(['plan', DEFAULT_MISSION_PATH, '--out', str(slow)]) == 0
    assert main(['plan', DEFAULT_MISSION_PATH, '--out', str(fast), '--speed', '2']) == 0
    t_slow = json.loads(slow.read_text())['summary']['time_planned_s']
    t_fast = json.loads(fast.read_text())['summary']['time_planned_s']
    assert t_fast == pytest.approx(t_slow / 4)


@pytest.mark.parametrize('args,words', [
    (['--speed', '0'], '--speed 0 refused: must be > 0'),
    (['--out', 'X', '--csv', '-5'], '--csv -5 refused: must be > 0'),
    (['--csv', '100'], '--csv needs --out'),
])
def test_bad_plan_requests_exit_2_with_the_reason(tmp_path, capsys, args, words):
    args = [a.replace('X', str(tmp_path / 'x.json')) for a in args]
    assert main(['plan', DEFAULT_MISSION_PATH, *args]) == 2
    assert words in capsys.readouterr().err
    assert not os.path.exists(tmp_path / 'x.json')


def test_missing_mission_file(tmp_path, capsys):
    assert main(['plan', str(tmp_path / 'none.yaml')]) == 2
    assert 'none.yaml: no such file' in capsys.readouterr().err


# --- what the plan command costs (issue: 1 s of a 1.3 s plan was imports; 10,001 waypoints took 505 MiB) ------

def test_plan_imports_neither_ros_nor_scipy_for_a_small_plan(tmp_path):
    """Lazy imports: the CLI imports only the plan subcommand's module (timed in bench/bench_plan.py)."""
    import subprocess
    import sys

    code = ('import sys; from quad_bringup.cli import main; '
            f'assert main(["plan", {DEFAULT_MISSION_PATH!r}, "--out", {str(tmp_path / "t.json")!r}]) == 0; '
            'heavy = sorted(m for m in sys.modules if m.split(".")[0] in ("rclpy", "scipy", "rosbags", "matplotlib") '
            'or m == "numpy.ma"); print("HEAVY", heavy)')
    done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, env=os.environ, check=True)
    assert 'HEAVY []' in done.stdout, done.stdout


def test_plan_json_is_exactly_json_dumps_of_the_plan(tmp_path):
    """The JSON is written per axis by json's C encoder, not per value; the text is the same as json.dumps."""
    from quad_trajectory.mission import load_mission, plan_mission

    long = DEFAULT_MISSION_PATH.replace('maze.yaml', 'long_100.yaml')
    for path in (DEFAULT_MISSION_PATH, long):
        result = plan_mission(load_mission(path))
        assert result.to_json(mission='a "quoted" path') == json.dumps({'mission': 'a "quoted" path',
                                                                      **result.to_dict()})


def test_many_waypoints_plan_end_to_end(tmp_path):
    """10,001 waypoints through the command: YAML (C loader + numbers fast path) to JSON."""
    rng = np.random.default_rng(3)
    steps = rng.uniform(0.4, 1.2, (10000, 1)) * np.column_stack([np.cos(np.arange(10000) * 0.7),
                                                                  np.sin(np.arange(10000) * 0.7), np.zeros(10000)])
    w = np.vstack([[0, 0, 1], np.cumsum(steps, axis=0) + [0, 0, 1]])
    mission = tmp_path / 'survey.yaml'
    mission.write_text('waypoints:\n' + ''.join(f'  - [{x:.4f}, {y:.4f}, {z:.4f}]\n' for x, y, z in w))
    out = tmp_path / 'survey.json'
    assert main(['plan', str(mission), '--out', str(out)]) == 0
    data = json.loads(out.read_text())
    assert len(data['segments']) == 10000 and data['summary']['segments'] == 10000
    np.testing.assert_allclose(data['waypoints'], np.round(w, 4))
    traj = PiecewisePolynomial.from_dict(data)
    np.testing.assert_allclose(traj.evaluate(traj.breaks_s)[:, :3], np.round(w, 4), atol=1e-6)


# --- time allocation: plan takes every option fly does (plan must not advise an option it does not accept) ----

def _choices(command, option='--time-allocation'):
    from quad_bringup.cli import build_parser
    sub = next(a for a in build_parser(command)._actions if getattr(a, 'choices', None) and command in a.choices)
    return next(a for a in sub.choices[command]._actions if option in a.option_strings).choices


def test_plan_and_fly_accept_the_same_time_allocations_and_fastest_round_trips(tmp_path, capsys):
    from quad_bringup.cli import build_parser
    from quad_bringup.commands.fly import options_from
    assert tuple(_choices('plan')) == tuple(_choices('fly')) and 'fastest' in _choices('plan')
    fly_args = build_parser('fly').parse_args(['fly', DEFAULT_MISSION_PATH, '--time-allocation', 'fastest'])
    assert options_from(fly_args).time_allocation == 'fastest'
    out = tmp_path / 'fast.json'
    assert main(['plan', DEFAULT_MISSION_PATH, '--time-allocation', 'fastest', '--out', str(out)]) == 0
    printed = capsys.readouterr().out
    data = json.loads(out.read_text())
    assert data['time_allocation'] == 'fastest' and "fastest: the shortest plan found within crazyflie's" in printed
    seed = tmp_path / 'seed.json'
    assert main(['plan', DEFAULT_MISSION_PATH, '--speed', '2', '--out', str(seed)]) == 0
    assert data['summary']['time_planned_s'] < json.loads(seed.read_text())['summary']['time_planned_s']


def test_plan_refuses_an_unknown_time_allocation(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(['plan', DEFAULT_MISSION_PATH, '--time-allocation', 'fastests'])
    assert exit_info.value.code == 2 and "invalid choice: 'fastests'" in capsys.readouterr().err


def test_plan_prints_the_refusal_advice_naming_fastest(capsys):
    figure8 = DEFAULT_MISSION_PATH.replace('maze.yaml', 'figure8.yaml')
    assert main(['plan', figure8, '--speed', '2']) == 0      # written either way; fly refuses it
    printed = capsys.readouterr().out
    assert 'NOT feasible on crazyflie' in printed and 'time_allocation fastest fits: ' in printed
    advice = next(line for line in printed.splitlines() if line.startswith('time_allocation fastest fits'))
    assert main(['plan', figure8, *advice.split(': ')[2].split(', or')[0].split()]) == 0   # the advice, taken
    assert 'feasible on crazyflie' in capsys.readouterr().out
