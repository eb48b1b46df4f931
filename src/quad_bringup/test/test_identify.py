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


@pytest.fixture(scope='module')
def lag_bag(tmp_path_factory):
    return flown_bag(tmp_path_factory.mktemp('identify'), 'autopilot_lag')


def identify_cli(*args):
    return subprocess.run([sys.executable, '-m', 'quad_bringup.cli', 'identify', *map(str, args)],
                          capture_output=True, text=True, cwd=REPO_ROOT)


def test_cli_writes_a_profile_the_controller_flies(tmp_path, lag_bag):
    """The default base is the real-vehicle profile (what the bridge flies); it has margin on the lag found."""
    out = tmp_path / 'profile.yaml'
    done = identify_cli(lag_bag, '--out', out)
    assert done.returncode == 0, done.stderr
    assert 'roll : lag 0.1' in done.stdout and 'thrust: scale' in done.stdout
    assert 'margin (1.5x the lag 0.1' in done.stdout and '0.050 s, pid): ' in done.stdout
    assert 'telemetry latency 0.100 s' in done.stdout and ': settled' in done.stdout
    written = yaml.safe_load(out.read_text())
    params = written['position_controller']['ros__parameters']
    assert params['controller'] == 'pid' and params['attitude_lead_s'] == pytest.approx(0.15, rel=0.15)
    assert params['thrust_scale'] == pytest.approx(1.0, abs=0.01)
    assert params['kp_x'] == yaml.safe_load(resolve_config('config/control_real.yaml').read_text())[
        'position_controller']['ros__parameters']['kp_x']
    margin = written['identification']['margin']
    assert margin['lag_s'] == pytest.approx(1.5 * written['identification']['attitude_lead_s'], abs=1e-3)
    assert margin['latency_s'] == pytest.approx(0.1) and margin['oscillation_deg'] < 0.5


def test_cli_refuses_a_profile_without_margin(tmp_path, lag_bag):
    """control_fast behind 1.5x the identified lag (0.15 s) and 2x the latency oscillates: nothing is written."""
    out = tmp_path / 'fast.yaml'
    done = identify_cli(lag_bag, '--base', resolve_config('config/control_fast.yaml'), '--out', out,
                        '--latency-s', '0.05')
    assert done.returncode == 2, done.stdout
    assert not out.exists()
    message = done.stderr
    assert f'refused to write {out}' in message and 'se3' in message and 'control_fast.yaml' in message
    assert 's of attitude lag' in message and '0.100 s of telemetry latency' in message
    lag = float(message.split(' does not settle at ')[1].split(' s')[0])
    assert lag == pytest.approx(0.225, rel=0.15)
    tilt = float(message.split('(tilt ')[1].split(' deg')[0])
    oscillation = float(message.split('oscillation ')[1].split(' deg')[0])
    assert tilt > 20.0 and oscillation > 10.0
    assert 'NOT settled' in done.stdout


def test_cli_refuses_a_bad_latency_by_name(lag_bag):
    done = identify_cli(lag_bag, '--latency-s', 'nan')
    assert done.returncode == 2 and '--latency-s nan refused' in done.stderr


def test_a_bag_without_commands_is_refused_by_name(tmp_path):
    from quad_bringup.recorder import DEFAULT_TOPICS, BagRecorder
    bag = tmp_path / 'empty'
    recorder = BagRecorder(bag)
    recorder.add_topic('odom', DEFAULT_TOPICS['odom'])
    recorder.close()
    done = subprocess.run([sys.executable, '-m', 'quad_bringup.cli', 'identify', str(bag)],
                          capture_output=True, text=True, cwd=REPO_ROOT)
    assert done.returncode == 2 and 'quadflight identify:' in done.stderr and 'odom' in done.stderr
