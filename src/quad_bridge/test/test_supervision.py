"""What a quiet setpoint stream or an ended hand-over commands (quad_bridge.supervision), on the real backends."""

import pytest

from quad_bridge import supervision as sv
from quad_bridge.ardupilot import ArduPilot
from quad_bridge.link import LinkState
from quad_bridge.px4 import Px4
from quad_common import diagnostics


@pytest.mark.parametrize('backend, mode, stale_action, expected', [
    (Px4(), 'OFFBOARD', 'land', 'AUTO.LAND'),
    (Px4(), 'OFFBOARD', 'hold', 'AUTO.LOITER'),
    (ArduPilot(), 'GUIDED', 'hold', 'LAND'),             # ArduPilot always lands
    (ArduPilot(), 'GUIDED_NOGPS', 'land', 'LAND'),
])
def test_stale_action_mode_for_an_armed_vehicle_flying_setpoints(backend, mode, stale_action, expected):
    assert sv.stale_action_mode(backend, True, mode, stale_action) == expected


@pytest.mark.parametrize('backend, armed, mode', [
    (None, True, 'OFFBOARD'),             # no heartbeat yet: no backend
    (Px4(), False, 'OFFBOARD'),           # disarmed: nothing flies
    (Px4(), True, 'AUTO.LAND'),           # after our own land: nothing but land (that mode obeys no setpoint)
    (ArduPilot(), True, 'LOITER'),
    (Px4(), True, None),
])
def test_no_stale_action_unless_armed_in_a_mode_that_obeys_setpoints(backend, armed, mode):
    assert sv.stale_action_mode(backend, armed, mode, 'land') is None


def test_quiet_stream_commands_the_mode_only_with_the_link_up_and_says_why():
    up = sv.quiet_stream(True, 0.5, 'LAND', 'GUIDED', LinkState.UP)
    assert up.command == 'LAND' and up.error
    assert up.message == ('setpoints stale (none for 0.5 s): commanding LAND (the vehicle in GUIDED keeps flying '
                          'the last setpoint)')
    lost = sv.quiet_stream(True, 0.5, 'LAND', 'GUIDED', LinkState.LOST)
    assert lost.command is None and lost.error and 'while the link is lost' in lost.message
    quiet = sv.quiet_stream(False, 0.5, 'LAND', 'GUIDED', LinkState.UP)   # wire quiet, setpoints fresh
    assert quiet.command == 'LAND' and quiet.error and quiet.message.startswith('setpoint stream stopped: ')


def test_quiet_stream_with_nothing_obeying_is_an_info_unless_stale():
    info = sv.quiet_stream(False, 0.5, None, 'POSCTL', LinkState.UP)
    assert info.command is None and not info.error
    assert info.message == 'setpoint stream stopped: nothing commanded (vehicle in POSCTL, not flying our setpoints)'
    assert sv.quiet_stream(True, 0.5, None, None, LinkState.UP).error
    assert '(vehicle in ?,' in sv.quiet_stream(True, 0.5, None, None, LinkState.UP).message


def test_an_ended_hand_over_commands_only_over_a_live_link():
    assert sv.hand_over_ended_command('AUTO.LAND', LinkState.UP) == 'AUTO.LAND'
    assert sv.hand_over_ended_command('AUTO.LAND', LinkState.LOST) is None
    assert sv.hand_over_ended_command(None, LinkState.UP) is None


def test_link_level_up_waiting_lost_degraded_and_refused():
    ok, warn, error = diagnostics.OK, diagnostics.WARN, diagnostics.ERROR
    assert sv.link_level(LinkState.UP, False, False) == ok
    assert sv.link_level(LinkState.UP, True, False) == warn
    assert sv.link_level(LinkState.WAITING, False, False) == warn
    assert sv.link_level(LinkState.WAITING, True, False) == warn
    assert sv.link_level(LinkState.LOST, False, False) == error
    for state in (LinkState.UP, LinkState.WAITING, LinkState.LOST):
        assert sv.link_level(state, False, True) == error


def test_setpoints_level_warns_after_a_stale_stream_a_breach_or_a_refused_source():
    assert sv.setpoints_level(0, False, 0) == diagnostics.OK
    assert sv.setpoints_level(1, False, 0) == diagnostics.WARN
    assert sv.setpoints_level(0, True, 0) == diagnostics.WARN
    assert sv.setpoints_level(0, False, 3) == diagnostics.WARN
