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
    (['--speed', '0'], 'speed = 0.0'),
    (['--out', 'X', '--csv', '-5'], 'rate_hz = -5.0'),
    (['--csv', '100'], '--csv needs --out'),
])
def test_bad_plan_requests_exit_2_with_the_reason(tmp_path, capsys, args, words):
    args = [a.replace('X', str(tmp_path / 'x.json')) for a in args]
    assert main(['plan', DEFAULT_MISSION_PATH, *args]) == 2
    assert words in capsys.readouterr().err
    assert not os.path.exists(tmp_path / 'x.json')


def test_missing_mission_file(tmp_path, capsys):
    assert main(['plan', str(tmp_path / 'none.yaml')]) == 2
    assert 'none.yaml: file not found' in capsys.readouterr().err
