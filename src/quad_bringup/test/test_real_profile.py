"""The real-vehicle profile (config/control_real.yaml, what the bridge launch files fly) checked in quad_sim
against an autopilot-like attitude loop with the lags measured on ArduCopter (roll/pitch 0.17-0.21 s) and
~50 ms of telemetry: no oscillation, margin to 1.5x the lag and 2x the delay, and a hover within 1 cm with a
6 % hover-thrust error. The same check catches the fast profile that flipped ArduCopter."""

import pytest

from quad_bringup.closed_loop import hold_offline, load_control_profile
from quad_common.paths import resolve_config

VEHICLE = resolve_config('config/vehicles/px4_quad.yaml')
REAL = resolve_config('config/control_real.yaml')


def autopilot(lag_s, thrust_error=0.0):
    """ArduPilot-like: the attitude target follows the setpoint with a first-order lag (its input shaping)."""
    return {'attitude_loop': {'type': 'lag', 'time_constant_s': lag_s}, 'thrust_error': thrust_error}


@pytest.mark.parametrize('lag_s, latency_s, thrust_error', [(0.17, 0.05, -0.06), (0.21, 0.05, 0.06),
                                                             (0.315, 0.1, -0.06)])
def test_real_profile_holds_within_a_centimetre_without_oscillation(lag_s, latency_s, thrust_error):
    controller, gains = load_control_profile(REAL)
    hold = hold_offline(VEHICLE, controller, gains, plant=autopilot(lag_s, thrust_error), odom_latency_s=latency_s)
    assert hold['offset_m'] < 0.01
    assert hold['late_tilt_deg'] < 1.0 and hold['peak_tilt_deg'] < 20.0


def test_seed_pd_sits_off_with_a_hover_thrust_error():
    """What the profile's integral action removes (13: a seed-PD hover sat 3 cm off on ArduCopter)."""
    controller, gains = load_control_profile(resolve_config('config/control.yaml'))
    assert controller == 'pd'
    hold = hold_offline(VEHICLE, controller, gains, plant=autopilot(0.19, -0.06), odom_latency_s=0.05)
    assert hold['offset_m'] > 0.02


@pytest.mark.parametrize('profile', ['config/control_fast.yaml', 'config/control_se3.yaml'])
def test_fast_profiles_oscillate_against_the_tilt_clamp_behind_an_autopilot(profile):
    controller, gains = load_control_profile(resolve_config(profile))
    hold = hold_offline(VEHICLE, controller, gains, plant=autopilot(0.19), odom_latency_s=0.05, duration_s=12.0)
    assert hold['late_tilt_deg'] > 25.0
