"""What a quiet setpoint stream or an ended hand-over commands (quad_bridge.supervision), on the real backends; the
Supervisor's reactions and periodic checks against a recording client."""

from types import SimpleNamespace

import numpy as np
import pytest
from bridge_fakes import bridge, fly

from quad_bridge import supervision as sv
from quad_bridge.ardupilot import ArduPilot
from quad_bridge.geofence import Geofence
from quad_bridge.link import LinkState
from quad_bridge.mavlink_client import mavlink
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


def test_a_stale_stream_ends_the_hand_over_and_commands_stale_action_once_per_stale_spell():
    b = bridge(ArduPilot())
    fly(b, 'GUIDED_NOGPS')
    b.supervisor.on_stream_quiet(0.6, 0.6)
    assert b.supervisor.stale_events == 1 and not b.vehicle.handover.active
    assert b.client.commands[-1][2:] == (mavlink.MAV_CMD_DO_SET_MODE, [1, *ArduPilot().mode_params('LAND')], None)
    assert b.log.lines[-1] == ('error', 'setpoints stale (none for 0.5 s): commanding LAND (the vehicle in '
                                        'GUIDED_NOGPS keeps flying the last setpoint)')
    assert b.diagnostics == 1
    b.supervisor.on_stream_quiet(0.6, 0.1)     # wire quiet, setpoints fresh: after our LAND nothing is commanded
    assert b.supervisor.stale_events == 1 and len(b.client.commands) == 1 and b.log.lines[-1][0] == 'info'


def test_a_link_loss_that_ended_a_hand_over_commands_stale_action_when_the_link_is_back():
    b = bridge(Px4())
    fly(b, 'OFFBOARD')
    b.client.drained_s = b.now_s() + 5.0        # the receive thread read all there was, until 5 s later
    b.supervisor.tick(b.now_s() + 5.0)          # nothing from the vehicle for 5 s > link_timeout_s
    assert b.link.state == LinkState.LOST and not b.vehicle.handover.active
    assert ('error', 'vehicle link lost (nothing for 2.0 s)') in b.log.lines
    assert b.supervisor.lost_while_handed_over and not b.client.commands
    b.supervisor.after_link_loss()
    assert b.client.commands[-1][2:4] == (mavlink.MAV_CMD_DO_SET_MODE, [1, *Px4().mode_params('AUTO.LAND')])
    assert b.supervisor.stale_events == 1 and not b.supervisor.lost_while_handed_over
    b.supervisor.after_link_loss()             # once
    assert len(b.client.commands) == 1


def test_an_external_pose_fault_ends_the_hand_over_and_only_while_handed_over():
    b = bridge(Px4(), params={'stale_action': 'hold'})
    b.supervisor.on_external_pose_fault('timeout (no pose for 0.5 s)')
    assert b.supervisor.external_pose_faults == 0 and not b.client.commands
    fly(b, 'OFFBOARD')
    b.supervisor.on_external_pose_fault('jump 2.00 m')
    assert b.supervisor.external_pose_faults == 1
    assert b.client.commands[-1][3] == [1, *Px4().mode_params('AUTO.LOITER')]
    assert b.log.lines[-1] == ('error', 'external pose: jump 2.00 m: hand-over ended, commanding AUTO.LOITER')


def test_the_geofence_brakes_then_lands_on_a_breach():
    b = bridge(Px4())
    fly(b, 'OFFBOARD')
    b.geofence = Geofence(True, [-1, -1, -1], [1, 1, 2])
    b.engaged = True
    state = SimpleNamespace(position=np.array([0.0, 0.0, 1.0]), velocity=np.array([3.0, 0.0, 0.0]))
    b.supervisor.on_state(state)
    assert b.geofence.braking and b.streamer.kicks == 1 and b.log.lines[-1][1].startswith('geofence ahead: braking')
    state.position = np.array([1.5, 0.0, 1.0])
    b.supervisor.on_state(state)
    assert not b.vehicle.handover.active and b.client.commands[-1][3] == [1, *Px4().mode_params('AUTO.LAND')]
    assert b.log.lines[-1] == ('error', 'geofence: left the box at [1.5, 0.0, 1.0]: streaming stopped, landing')


def test_a_second_vehicle_on_the_link_ends_the_hand_over_once():
    b = bridge(Px4())
    fly(b, 'OFFBOARD')
    b.link_refusal = lambda: 'two vehicles as system 1'
    b.supervisor.check_link_peers()
    b.supervisor.check_link_peers()
    assert not b.vehicle.handover.active and b.log.lines == [('error', 'two vehicles as system 1')]


def test_the_supervisor_beats_once_a_second_with_timesync_and_diagnostics():
    b = bridge(Px4())
    for now in (10.0, 10.5, 11.0, 11.5):
        b.supervisor.tick(now)
    beats = [args for name, args in b.client.sent if name == 'heartbeat']
    assert beats == [(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                      mavlink.MAV_STATE_ACTIVE)] * 2
    assert b.telemetry.timesyncs == 2 and b.diagnostics == 2


def test_a_supervisor_error_is_logged_and_the_thread_goes_on():
    b = bridge(Px4())
    calls = []

    def tick(now):
        calls.append(now)
        if len(calls) == 1:
            raise RuntimeError('boom')
        b.stopping.set()
    b.supervisor.tick = tick
    b.supervisor.run(b.stopping)
    assert len(calls) == 2 and b.log.lines == [('error', "supervisor: RuntimeError('boom')")]
