"""The real-vehicle profile (config/control_real.yaml, what the bridge launch files fly) checked on the emulator's
attitude response (quad_bringup.offline.stability: quad_sim behind quad_vehicle_emu's shaping and telemetry delay line)
with the lags measured on ArduCopter (roll/pitch 0.17-0.21 s) and ~50 ms of telemetry: a hover within 1 cm with a
6 % hover-thrust error, and margin: it settles at 1.5x the lag and 2x the latency. The same check catches the
profiles that oscillate behind an autopilot (control_fast flipped ArduCopter)."""

import math

import numpy as np
import pytest

from quad_bringup.analysis.identify import DT_S, fit_fopdt
from quad_bringup.offline.closed_loop import load_control_profile
from quad_bringup.offline.stability import (
    MARGIN_LAG,
    MARGIN_LATENCY,
    MEASURED_LAG_S,
    MEASURED_LATENCY_S,
    hold_on_autopilot,
    margin_hold,
)
from quad_common import rotations
from quad_common.paths import resolve_config
from quad_common.types import GRAVITY_MPS2, AttitudeSetpoint
from quad_sim.simulator import Simulator
from quad_vehicle_emu.attitude import AttitudeResponse, emulated_vehicle, tau_for_lag_s

VEHICLE = resolve_config('config/vehicles/px4_quad.yaml')
REAL = resolve_config('config/control_real.yaml')


@pytest.mark.parametrize('lag_s', [0.17, 0.21, 0.315])
def test_emulator_shaping_gives_the_requested_lag(lag_s):
    """tau_for_lag_s: identify's FOPDT fit of the emulator's roll response (shaping + the autopilot's quaternion
    loop, as mavlink_vehicle steps them) to a random staircase of roll commands finds the requested lag (tau +
    dead time)."""
    vehicle = emulated_vehicle(VEHICLE)
    sim = Simulator(vehicle, physics_rate_hz=500.0, initial_position=(0.0, 0.0, 50.0), setpoint_timeout_s=1e6)
    shaper = AttitudeResponse(tau_for_lag_s(vehicle, lag_s), sim.state.quaternion)
    rng = np.random.default_rng(1)
    commands = np.repeat(np.radians(rng.uniform(-8.0, 8.0, 16)), int(round(1.0 / DT_S)))
    measured = []
    for roll in commands:
        q, w = shaper.step(rotations.from_euler(roll, 0.0, 0.0), DT_S)
        sim.set_setpoint(AttitudeSetpoint(quaternion=q, specific_force_mps2=GRAVITY_MPS2 / math.cos(roll),
                                          body_rates=w))
        sim.advance(DT_S)
        measured.append(rotations.to_euler(sim.state.quaternion)[0])
    tau, delay, gain, _, _ = fit_fopdt(commands, np.array(measured))
    # within 0.02 s: the autopilot loop (second order) fits a little short when shaping is small (0.17 s: 0.152)
    assert tau + delay == pytest.approx(lag_s, abs=0.02)
    assert gain == pytest.approx(1.0, abs=0.05)


def test_shaping_cannot_be_faster_than_the_vehicles_own_loop():
    with pytest.raises(ValueError, match='0.05'):
        tau_for_lag_s(emulated_vehicle(VEHICLE), 0.05)


@pytest.mark.parametrize('lag_s', MEASURED_LAG_S)
@pytest.mark.parametrize('thrust_error', [-0.06, 0.06])
def test_real_profile_holds_within_a_centimetre_at_the_measured_lags(lag_s, thrust_error):
    controller, gains = load_control_profile(REAL)
    hold = hold_on_autopilot(VEHICLE, controller, gains, lag_s, MEASURED_LATENCY_S, thrust_error)
    print(hold.describe())
    assert hold.offset_m < 0.01
    assert hold.settled and hold.late_tilt_deg < 0.5 and hold.peak_tilt_deg < 20.0


@pytest.mark.parametrize('thrust_error', [-0.06, 0.06])
def test_real_profile_settles_at_the_margin(thrust_error):
    """1.5x the largest measured lag (0.315 s) and 2x the latency (0.1 s): settled, no sustained oscillation."""
    controller, gains = load_control_profile(REAL)
    hold = margin_hold(VEHICLE, controller, gains, max(MEASURED_LAG_S), MEASURED_LATENCY_S, thrust_error)
    print(hold.describe())
    assert hold.lag_s == pytest.approx(MARGIN_LAG * 0.21) and hold.latency_s == pytest.approx(MARGIN_LATENCY * 0.05)
    assert hold.settled and hold.late_tilt_deg < 1.0 and hold.oscillation_deg < 0.25 and hold.offset_m < 0.01


def test_margin_has_an_edge():
    """The check can fail the real profile too: far beyond the margin (0.6 s of lag) it oscillates."""
    controller, gains = load_control_profile(REAL)
    hold = hold_on_autopilot(VEHICLE, controller, gains, 0.6, 2 * MEASURED_LATENCY_S)
    print(hold.describe())
    assert not hold.settled and hold.oscillation_deg > 2.0


def test_seed_pd_sits_off_with_a_hover_thrust_error():
    """What the profile's integral action removes (13: a seed-PD hover sat 3 cm off on ArduCopter)."""
    controller, gains = load_control_profile(resolve_config('config/control.yaml'))
    assert controller == 'pd'
    hold = hold_on_autopilot(VEHICLE, controller, gains, 0.19, MEASURED_LATENCY_S, -0.06)
    print(hold.describe())
    assert hold.offset_m > 0.02


@pytest.mark.parametrize('profile', ['config/control_fast.yaml', 'config/control_se3.yaml'])
def test_fast_profiles_oscillate_against_the_tilt_clamp_behind_an_autopilot(profile):
    """13: control_fast oscillated at 0.8 Hz against the 35-degree clamp on ArduCopter, then flipped."""
    controller, gains = load_control_profile(resolve_config(profile))
    hold = hold_on_autopilot(VEHICLE, controller, gains, 0.19, MEASURED_LATENCY_S, duration_s=12.0)
    print(hold.describe())
    assert not hold.settled
    assert hold.stopped or (hold.late_tilt_deg > 25.0 and hold.oscillation_deg > 10.0
                            and 0.4 < hold.oscillation_hz < 1.5)


def test_a_half_turn_of_yaw_with_an_offset_is_recovered_on_the_autopilots_loop():
    """The plan's yaw 180 deg from the vehicle's, 0.3 m off: the autopilot's quaternion loop tilts the right way
    while it turns (quad_sim's eq. 6 on Euler-angle differences tilts the wrong way and runs away ~40 m)."""
    controller, gains = load_control_profile(REAL)
    hold = hold_on_autopilot(VEHICLE, controller, gains, 0.19, 0.05, start_offset_m=(0.3, 0.0, 0.0),
                             initial_yaw_rad=math.pi, duration_s=15.0)
    assert hold.settled, hold.describe()
    assert hold.offset_m < 0.05
