"""The hand-over state machine (quad_bridge.handover) and the vehicle status it lives in."""

from quad_bridge import handover as ho
from quad_bridge.px4 import Px4
from quad_bridge.vehicle_state import Vehicle


def _px4_active():
    h = ho.Handover(confirm_timeout_s=3.0)
    h.request('OFFBOARD', prestream=True, now_s=0.0)
    assert h.phase == ho.PRESTREAM and h.may_stream('POSCTL')   # PX4's pre-stream before the switch
    h.acknowledged(True, 'MAV_RESULT_ACCEPTED', 0.5)
    assert h.phase == ho.ACTIVE and h.may_stream('POSCTL')      # ACK before the heartbeat shows it
    assert h.heartbeat('OFFBOARD', True, True, 1.0) is None and h.confirmed
    return h


def test_nothing_streams_before_an_explicit_offboard():
    h = ho.Handover()
    for mode in ('GUIDED', 'GUIDED_NOGPS', 'OFFBOARD'):
        assert not h.may_stream(mode)


def test_no_prestream_means_no_setpoint_before_the_ack():
    h = ho.Handover()
    h.request('GUIDED_NOGPS', prestream=False, now_s=0.0)
    assert h.phase == ho.SWITCHING and not h.may_stream('GUIDED')
    h.acknowledged(True, 'MAV_RESULT_ACCEPTED', 0.1)
    assert h.may_stream('GUIDED')          # accepted, the heartbeat has not caught up yet
    h.heartbeat('GUIDED_NOGPS', True, True, 0.5)
    assert h.may_stream('GUIDED_NOGPS') and not h.may_stream('GUIDED')


def test_a_refused_switch_ends_it():
    h = ho.Handover()
    h.request('OFFBOARD', prestream=True, now_s=0.0)
    h.acknowledged(False, 'MAV_RESULT_DENIED', 0.2)
    assert h.phase == ho.IDLE and 'MAV_RESULT_DENIED' in h.reason and not h.may_stream('OFFBOARD')


def test_a_mode_change_by_the_pilot_ends_it_and_coming_back_does_not_resume():
    h = _px4_active()
    assert 'mode changed to POSCTL' in h.heartbeat('POSCTL', True, True, 2.0)
    assert not h.may_stream('POSCTL')
    assert h.heartbeat('OFFBOARD', True, True, 3.0) is None
    assert not h.may_stream('OFFBOARD') and h.ended == 1


def test_land_and_disarm_end_it_and_rearming_never_resumes():
    h = _px4_active()
    assert h.end('land') == 'hand-over ended: land'
    assert h.end('again') is None                              # already idle
    h = _px4_active()
    assert h.heartbeat('OFFBOARD', False, True, 2.0) == 'hand-over ended: vehicle disarmed'
    # PX4 returns to OFFBOARD after the disarm; re-arming there never resumes the stream
    assert h.heartbeat('OFFBOARD', True, False, 3.0) is None and not h.may_stream('OFFBOARD')


def test_a_switch_never_shown_by_the_vehicle_ends_it():
    h = ho.Handover(confirm_timeout_s=1.0)
    h.request('GUIDED_NOGPS', prestream=False, now_s=0.0)
    h.acknowledged(True, 'ok', 0.0)
    assert h.heartbeat('LOITER', True, True, 0.5) is None
    assert 'never reported GUIDED_NOGPS' in h.heartbeat('LOITER', True, True, 1.5)


def test_vehicle_status_follows_heartbeats_under_its_lock():
    v = Vehicle()
    v.status.backend = Px4()
    assert v.heartbeat(0x00030000, True, 0.0) == (None, None)
    v.handover.request('OFFBOARD', True, 0.0)
    v.handover.acknowledged(True, 'ok', 0.1)
    assert v.heartbeat(0x00060000, True, 0.2) == ('POSCTL -> OFFBOARD', None) and v.may_stream()
    change, ended = v.heartbeat(0x03040000, True, 0.3)
    assert change == 'OFFBOARD -> AUTO.LOITER' and 'AUTO.LOITER' in ended and not v.may_stream()
    snap = v.snapshot()
    assert snap.mode == 'AUTO.LOITER' and snap is not v.status


def test_engaged_only_once_a_heartbeat_shows_the_mode():
    h = ho.Handover()
    h.request('OFFBOARD', prestream=True, now_s=0.0)
    h.acknowledged(True, 'MAV_RESULT_ACCEPTED', 1.0, mode='AUTO.LOITER')
    assert h.phase == ho.ACTIVE and not h.engaged               # accepted, not yet shown
    h.heartbeat('AUTO.LOITER', True, True, 1.2)
    assert not h.engaged
    h.heartbeat('OFFBOARD', True, True, 1.9)
    assert h.engaged
    early = ho.Handover()
    early.request('OFFBOARD', prestream=True, now_s=0.0)
    early.acknowledged(True, 'MAV_RESULT_ACCEPTED', 1.0, mode='OFFBOARD')   # its heartbeat came before the ACK was read
    assert early.engaged


def test_the_mode_we_commanded_counts_until_its_heartbeat_or_a_refusal():
    v = Vehicle(confirm_timeout_s=3.0)
    v.status.backend = Px4()
    v.heartbeat(Px4().custom_mode('OFFBOARD'), True, 0.0)
    v.command_sent('AUTO.LAND', 10.0)
    v.heartbeat(Px4().custom_mode('OFFBOARD'), True, 10.2)     # sent before our command
    assert v.status.mode == 'OFFBOARD' and v.mode_now(10.5) == 'AUTO.LAND'
    v.heartbeat(Px4().custom_mode('AUTO.LAND'), True, 11.0)
    assert v.commanded is None and v.mode_now(11.0) == 'AUTO.LAND'
    v.command_sent('AUTO.LOITER', 20.0)
    assert v.mode_now(22.9) == 'AUTO.LOITER' and v.mode_now(23.1) == 'AUTO.LAND'   # never shown: the heartbeat's
    v.command_sent('AUTO.LOITER', 30.0)
    v.command_answered('AUTO.LOITER', accepted=False)
    assert v.mode_now(30.1) == 'AUTO.LAND'
