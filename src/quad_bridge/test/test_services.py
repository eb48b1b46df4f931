"""What the arm / offboard / land services do and answer (quad_bridge.services), on the real backends and hand-over,
against a recording client: the refusals in their order, the answers' texts, the hand-over they start or end,
and the landing on shutdown."""

import time

from bridge_fakes import Client, Streamer, bridge, fly

from quad_bridge import handover as ho
from quad_bridge import services as sv
from quad_bridge.ardupilot import ArduPilot
from quad_bridge.backend import ParamCheck
from quad_bridge.link import LinkState
from quad_bridge.mavlink_client import mavlink
from quad_bridge.px4 import Px4

OK, DENIED = mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_DENIED


def test_not_ready_without_a_heartbeat_with_a_signing_problem_or_a_link_not_up():
    assert sv.not_ready(None, None, '', LinkState.WAITING) == 'no vehicle heartbeat yet'
    assert sv.not_ready(1, None, 'signing: wrong key', LinkState.UP) == 'no vehicle heartbeat yet: signing: wrong key'
    assert sv.not_ready(1, Px4(), 'signing: wrong key', LinkState.UP) == 'signing: wrong key'
    assert sv.not_ready(1, Px4(), '', LinkState.LOST) == 'link lost'
    assert sv.not_ready(1, Px4(), '', LinkState.UP) == ''


def test_every_service_refuses_first_when_the_link_is_refused():
    b = bridge(Px4())
    b.link_refusal = lambda: 'two vehicles answer as system 1'
    assert b.services.arm(True) == (False, 'two vehicles answer as system 1')
    assert b.services.offboard(True) == (False, 'two vehicles answer as system 1')
    assert b.services.land() == (False, 'two vehicles answer as system 1')
    assert not b.client.commands


def test_a_refused_command_answers_with_what_the_vehicle_said_since():
    b = bridge(Px4(), client=Client(result=DENIED))
    sent_ns = time.time_ns()
    b.vehicle.texts.add(sent_ns - 1, 4, 'before the command')
    b.vehicle.texts.add(sent_ns + 1, 4, 'Arming denied: Resolve system health failures first')
    assert b.services.answer('arm', DENIED, sent_ns) == (
        False, 'arm: MAV_RESULT_DENIED: the vehicle says "Arming denied: Resolve system health failures first"')
    assert b.services.answer('arm', OK, sent_ns) == (True, 'arm: MAV_RESULT_ACCEPTED')
    assert sv.refused_answer('mode AUTO.LAND', None, []) == 'mode AUTO.LAND: no COMMAND_ACK (timeout)'


def test_arm_is_refused_as_the_backend_says_and_disarm_while_flying_our_setpoints():
    b = bridge(Px4())
    b.vehicle.heartbeat(Px4().custom_mode('OFFBOARD'), False, b.now_s())
    assert b.services.arm(True) == (False, f'arm refused: {Px4().arm_refusal("OFFBOARD", False)}')
    fly(b, 'OFFBOARD')
    assert b.services.arm(False) == (False, 'disarm refused: the vehicle is flying our setpoints; call land first '
                                            '(a disarm in the air drops it)')
    assert not b.client.commands
    b.vehicle.handover.end('land')
    assert b.services.arm(False) == (True, 'disarm: MAV_RESULT_ACCEPTED')
    assert b.client.commands[-1][2:4] == (mavlink.MAV_CMD_COMPONENT_ARM_DISARM, [0.0])


def test_offboard_is_refused_for_parameter_problems_then_without_a_stream_from_the_source():
    b = bridge(ArduPilot())
    b.commander.current_check = lambda: ParamCheck(problems=('GUID_TIMEOUT = 0', 'ATC_ANGLE_BOOST = 0'))
    assert b.services.offboard(True) == (False, 'offboard refused: GUID_TIMEOUT = 0; ATC_ANGLE_BOOST = 0')
    b.commander.current_check = lambda: ParamCheck()
    b.streamer = Streamer(fresh=False)
    assert b.services.offboard(True) == (False, 'no live setpoint stream: publish cmd/attitude_thrust first')
    b.setpoints.refused_sources = lambda: '/intruder (3)'
    assert b.services.offboard(True) == (False, 'no live setpoint stream: publish cmd/attitude_thrust first (refused, '
                                                'not setpoint_source /position_controller: /intruder (3))')
    assert b.vehicle.handover.phase == ho.IDLE and not b.client.commands


def test_offboard_switches_and_the_hand_over_follows_the_ack():
    b = bridge(ArduPilot())                          # no pre-stream: DO_SET_MODE at once
    b.commander.current_check = lambda: ParamCheck()
    b.geofence.breached = True
    assert b.services.offboard(True) == (True, 'mode GUIDED_NOGPS: MAV_RESULT_ACCEPTED')
    assert b.vehicle.handover.phase == ho.ACTIVE and not b.geofence.breached and b.streamer.kicks == 2
    assert b.client.commands[-1][2:4] == (mavlink.MAV_CMD_DO_SET_MODE, [1, *ArduPilot().mode_params('GUIDED_NOGPS')])
    b.client.result = DENIED
    b.services.offboard(True)
    assert b.vehicle.handover.phase == ho.IDLE and 'MAV_RESULT_DENIED' in b.vehicle.handover.reason


def test_the_pre_stream_refuses_below_5_hz_or_when_the_hand_over_ended_meanwhile():
    b = bridge(Px4())
    b.services.prestream_s = 0.0
    b.commander.current_check = lambda: ParamCheck()
    b.streamer = Streamer(rate_hz=4.0)
    assert b.services.offboard(True) == (False, 'no live setpoint stream: 4.0 Hz sent')
    assert b.vehicle.handover.phase == ho.IDLE
    assert b.vehicle.handover.reason.endswith(': the pre-stream did not reach 5.0 Hz')
    assert not b.client.commands                     # nothing asked of the vehicle
    b.vehicle.handover.request('OFFBOARD', True, b.now_s())
    b.vehicle.handover.end('link lost')
    assert b.services.prestream() == 'offboard refused during the pre-stream: hand-over ended: link lost'


def test_offboard_false_holds_but_after_land_commands_nothing():
    b = bridge(Px4())
    fly(b, 'OFFBOARD')
    assert b.services.offboard(False) == (True, 'mode AUTO.LOITER: MAV_RESULT_ACCEPTED')
    assert b.vehicle.handover.reason.endswith(': offboard false')
    assert b.services.land() == (True, 'mode AUTO.LAND: MAV_RESULT_ACCEPTED')
    commands = len(b.client.commands)
    assert b.services.offboard(False) == (True, 'vehicle in AUTO.LAND: nothing commanded')
    assert len(b.client.commands) == commands


def test_shutdown_lands_a_vehicle_flying_our_setpoints_over_a_live_link_only():
    b = bridge(Px4())
    assert b.services.land_on_shutdown() is None and not b.client.commands   # not handed over: nothing
    fly(b, 'OFFBOARD')
    assert b.services.land_on_shutdown() == OK
    assert b.vehicle.handover.reason.endswith(': the bridge is shutting down')
    assert b.log.lines == [('warn', 'shutting down with the vehicle flying our setpoints: commanding AUTO.LAND'),
                           ('info', 'AUTO.LAND: MAV_RESULT_ACCEPTED')]
    b = bridge(ArduPilot())
    fly(b, 'GUIDED_NOGPS')
    b.link.update(b.now_s() + 5.0)
    assert b.services.land_on_shutdown() is None and not b.client.commands
    assert b.log.lines[-1][0] == 'error' and 'the link lost: nothing can be commanded' in b.log.lines[-1][1]
