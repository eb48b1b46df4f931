"""quadflight identify on rosbag2 bags flown by the plant family: the attitude lag within 15 % of the member's
own loop (quad_sim.stability.attitude_lag_s), the thrust scale of its mass / thrust error, a usable profile."""

import subprocess
import sys

import pytest
import yaml

from quad_bringup.closed_loop import LoopOptions, fly_offline
from quad_bringup.identify import identify
from quad_bringup.report import load_flight
from quad_common.paths import REPO_ROOT, resolve_config
from quad_common.vehicle import load_vehicle
from quad_sim.stability import attitude_lag_s

MAZE = resolve_config('config/missions/maze.yaml')
CRAZYFLIE = resolve_config('config/vehicles/crazyflie.yaml')


def flown_bag(tmp_path, member):
    """A bag of the seed pd flying the maze at 1 m/s on `member` (pd: no roll/pitch rate feed-forward)."""
    bag = tmp_path / f'{member}-bag'
    fly_offline(MAZE, LoopOptions(speed_mps=1.0, plant=member, bag_dir=bag))
    return bag


@pytest.mark.parametrize('member', ['nominal', 'slow_motors_72ms', 'autopilot_so3', 'autopilot_lag'])
def test_identified_attitude_lag_within_15_percent(tmp_path, member):
    vehicle = load_vehicle(CRAZYFLIE, plant=member)
    truth_s = attitude_lag_s(vehicle)
    result = identify(load_flight(flown_bag(tmp_path, member)))
    for axis in ('roll', 'pitch'):
        fit = result[axis]
        assert fit['lag_s'] == pytest.approx(truth_s, rel=0.15), (axis, fit)
        low, high = fit['lag_ci95_s']
        assert low < fit['lag_s'] < high and high - low < 0.3 * truth_s and fit['blocks'] >= 3
        assert fit['gain'] == pytest.approx(1.0, abs=0.05)
    assert result['thrust_scale'] == pytest.approx(1.0, abs=0.01)


@pytest.mark.parametrize('member, scale', [('heavy_20pct', 1 / 1.2), ('hover_thrust_error', 0.94)])
def test_thrust_scale_of_mass_and_hover_thrust_errors(tmp_path, member, scale):
    result = identify(load_flight(flown_bag(tmp_path, member)))
    thrust = result['thrust']
    assert thrust['thrust_scale'] == pytest.approx(scale, rel=0.01)
    low, high = thrust['thrust_scale_ci95']
    assert low <= thrust['thrust_scale'] <= high
    assert thrust['mass_error_equivalent'] == pytest.approx(1 / scale - 1, abs=0.015)


def test_cli_writes_a_profile_the_controller_flies(tmp_path):
    bag = flown_bag(tmp_path, 'autopilot_lag')
    out = tmp_path / 'profile.yaml'
    done = subprocess.run([sys.executable, '-m', 'quad_bringup.cli', 'identify', str(bag), '--out', str(out)],
                          capture_output=True, text=True, cwd=REPO_ROOT)
    assert done.returncode == 0, done.stderr
    assert 'roll : lag 0.1' in done.stdout and 'thrust: scale' in done.stdout
    params = yaml.safe_load(out.read_text())['position_controller']['ros__parameters']
    assert params['controller'] == 'se3' and params['attitude_lead_s'] == pytest.approx(0.15, rel=0.15)
    assert params['thrust_scale'] == pytest.approx(1.0, abs=0.01)


def test_a_bag_without_commands_is_refused_by_name(tmp_path):
    from quad_bringup.recorder import DEFAULT_TOPICS, BagRecorder
    bag = tmp_path / 'empty'
    recorder = BagRecorder(bag)
    recorder.add_topic('odom', DEFAULT_TOPICS['odom'])
    recorder.close()
    done = subprocess.run([sys.executable, '-m', 'quad_bringup.cli', 'identify', str(bag)],
                          capture_output=True, text=True, cwd=REPO_ROOT)
    assert done.returncode == 1 and 'quadflight identify:' in done.stderr and 'odom' in done.stderr
