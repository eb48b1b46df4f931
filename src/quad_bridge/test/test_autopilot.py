"""Mode encodings and thrust semantics of PX4 and ArduPilot Copter."""

import math

import pytest

from quad_bridge import autopilot as ap
from quad_common import rotations

PX4, APM = ap.MAV_AUTOPILOT_PX4, ap.MAV_AUTOPILOT_ARDUPILOTMEGA


def test_px4_custom_mode_packs_main_in_bits_16_23_and_sub_in_24_31():
    assert ap.px4_custom_mode(6) == 0x00060000 == 393216            # OFFBOARD
    assert ap.px4_custom_mode(4, 6) == 0x06040000 == 100925440      # AUTO.LAND
    assert ap.px4_decode(0x03040000) == (4, 3)                      # AUTO.LOITER
    assert ap.mode_name(PX4, 0x06040000) == 'AUTO.LAND'
    assert ap.mode_name(PX4, 0x00030000) == 'POSCTL'


def test_ardupilot_mode_numbers():
    assert ap.mode_name(APM, 4) == 'GUIDED'
    assert ap.mode_name(APM, 9) == 'LAND'
    assert ap.mode_name(APM, 20) == 'GUIDED_NOGPS'
    assert ap.mode_from_name(APM, 'GUIDED_NOGPS') == (20, 0)


def test_do_set_mode_params_are_small_values_not_a_packed_word():
    assert ap.mode_from_name(PX4, 'OFFBOARD') == (6, 0)
    assert ap.mode_from_name(PX4, 'AUTO.LAND') == (4, 6)
    assert ap.custom_mode_of(PX4, 4, 6) == ap.px4_custom_mode(4, 6)
    assert ap.custom_mode_of(APM, 9, 0) == 9


def test_unknown_mode_names_are_refused_by_name():
    with pytest.raises(ValueError, match='FLYING'):
        ap.mode_from_name(PX4, 'FLYING')
    with pytest.raises(ValueError, match='AUTO.NOPE'):
        ap.mode_from_name(PX4, 'AUTO.NOPE')
    with pytest.raises(ValueError, match='OFFBOARD'):
        ap.mode_from_name(APM, 'OFFBOARD')
    assert ap.mode_name(PX4, ap.px4_custom_mode(9)) == 'MAIN_9'


def test_px4_thrust_is_hover_throttle_at_g_and_clipped():
    assert ap.thrust_px4(9.81, 0.45) == pytest.approx(0.45)
    assert ap.thrust_px4(2 * 9.81, 0.3) == pytest.approx(0.6)
    assert ap.thrust_px4(100.0, 0.5) == 1.0
    assert ap.thrust_px4(0.0, 0.5) == 0.0


def test_ardupilot_thrust_is_not_boosted_twice():
    q = rotations.from_euler(math.radians(30.0), 0.0, 0.0)
    f = 9.81 / math.cos(math.radians(30.0))    # level flight at 30 deg bank needs g / cos(tilt)
    thrust = ap.thrust_ardupilot(f, 0.5, q)
    assert thrust == pytest.approx(0.5)          # the vehicle boosts 0.5 by 1/cos(30) itself
    assert ap.specific_force_from_thrust(APM, thrust, 0.5, q) == pytest.approx(f)
    assert ap.specific_force_from_thrust(PX4, ap.thrust_px4(f, 0.5), 0.5) == pytest.approx(f)


def test_climb_rate_semantics():
    assert ap.climb_rate_to_thrust(0.0, 2.5, 1.5) == 0.5
    assert ap.climb_rate_to_thrust(2.5, 2.5, 1.5) == 1.0
    assert ap.climb_rate_to_thrust(-1.5, 2.5, 1.5) == 0.0
    assert ap.climb_rate_to_thrust(1.25, 2.5, 1.5) == pytest.approx(0.75)
    for rate in (-1.5, -0.3, 0.0, 0.7, 2.5):
        assert ap.thrust_to_climb_rate(ap.climb_rate_to_thrust(rate, 2.5, 1.5), 2.5, 1.5) == pytest.approx(rate)
    # hover thrust at level attitude keeps the current vertical speed; 1 m/s^2 extra adds lead * 1 m/s
    level = rotations.from_yaw(0.3)
    assert ap.climb_rate_command(9.81, level, 0.4, 0.5) == pytest.approx(0.4)
    assert ap.climb_rate_command(10.81, level, 0.0, 0.5) == pytest.approx(0.5)
