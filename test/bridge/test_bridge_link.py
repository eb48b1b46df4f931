"""The bridge's link: a cut link is reported and recovered; garbage and foreign traffic never crash it; a udpin
link answers only its vehicle (a second local sender gets nothing and never stops the setpoints)."""

import math
import os
import random
import socket
import time

import pytest
from bridge_graph import SetpointPublisher, Tap, tapped_graph
from std_srvs.srv import SetBool, Trigger

from quad_bringup.emulated.vehicle_graph import free_udp_port, running_graph

os.environ['MAVLINK20'] = '1'
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402


@pytest.fixture
def graph(tmp_path):
    with running_graph(tmp_path) as g:
        yield g


def test_link_loss_is_reported_and_recovered(graph):
    procs, observer = graph
    bridge_port = free_udp_port()
    relay = Tap(bridge_port)
    try:
        procs.vehicle('px4', f'udpout:127.0.0.1:{relay.port}')
        procs.bridge(f'udpin:127.0.0.1:{bridge_port}', link_timeout_s=2.5)  # 1 Hz heartbeats, jittery machine
        observer.wait_for(lambda: observer.link()[0] == 'link up', 'link up')

        def count(key):
            return int(observer.link()[1].get(key, 0))

        losses, reconnects = count('losses'), count('reconnects')
        relay.cut.set()
        observer.wait_for(lambda: observer.link()[0] == 'link lost', 'the loss to be reported')
        assert count('losses') > losses
        assert not observer.call('offboard', SetBool.Request(data=True)).success  # nothing commanded while lost
        relay.cut.clear()
        observer.wait_for(lambda: observer.link()[0] == 'link up', 'the link to come back')
        assert count('reconnects') > reconnects
        n = len(observer.odom)
        observer.wait_for(lambda: len(observer.odom) > n + 10, 'odometry again')

        losses, reconnects = count('losses'), count('reconnects')
        procs.stop('vehicle')  # the vehicle process itself goes away and comes back
        observer.wait_for(lambda: count('losses') > losses, 'the loss of the stopped vehicle')
        procs.vehicle('px4', f'udpout:127.0.0.1:{relay.port}')
        observer.wait_for(lambda: count('reconnects') > reconnects, 'the restarted vehicle')
        assert 'vehicle link lost' in procs.log('bridge') and 'reconnected' in procs.log('bridge')
    finally:
        relay.close()


def _frames():
    """Malformed and foreign MAVLink: bad CRC, truncated, unknown id, v1, NaN telemetry, another system."""
    ours = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    foreign = mavlink.MAVLink(None, srcSystem=42, srcComponent=1)
    good = mavlink.MAVLink_local_position_ned_message(0, 1000.0, 1000.0, -1000.0, 0, 0, 0).pack(foreign)
    nan = mavlink.MAVLink_local_position_ned_message(0, math.nan, math.inf, 0.0, 0, 0, 0).pack(ours)
    hb = mavlink.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3).pack(foreign)
    gcs = mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3).pack(foreign)
    ack = mavlink.MAVLink_command_ack_message(400, 0, 0, 0, 1, 191).pack(foreign)
    bad_crc = bytearray(good)
    bad_crc[-1] ^= 0xFF
    unknown_id = bytearray(good)
    unknown_id[7:10] = (60000).to_bytes(3, 'little')
    v1 = bytes([0xFE, 9, 0, 1, 1, 0]) + bytes(9) + b'\x00\x00'
    huge_len = bytes([0xFD, 255, 0, 0, 0, 1, 1, 32, 0, 0]) + bytes(10)
    return [bytes(bad_crc), bytes(unknown_id), good[:7], good[:-3], v1, huge_len, nan, good, hb, gcs, ack, good * 3]


def test_garbage_and_foreign_traffic_leave_the_bridge_running(graph):
    procs, observer = graph
    port = free_udp_port()
    procs.vehicle('px4', f'udpout:127.0.0.1:{port}')
    bridge = procs.bridge(f'udpin:127.0.0.1:{port}', target_system=0)
    observer.wait_for(lambda: observer.link()[0] == 'link up', 'link up')

    rng = random.Random(7)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for k in range(400):
            sock.sendto(bytes(rng.getrandbits(8) for _ in range(rng.randint(1, 300))), ('127.0.0.1', port))
            if k % 4 == 0:
                for frame in _frames():
                    sock.sendto(frame, ('127.0.0.1', port))
        sock.sendto(b'\xfd' * 2000, ('127.0.0.1', port))
    finally:
        sock.close()

    n = len(observer.odom)
    observer.wait_for(lambda: len(observer.odom) > n + 50, 'odometry after the flood')
    observer.wait_for(lambda: int(observer.link()[1].get('bad_data', 0)) > 0, 'bad data to be counted')
    assert bridge.poll() is None
    message, values = observer.link()
    assert message == 'link up' and values['target_system'] == '1'
    with observer.lock:
        positions = [p for _, p in observer.odom]
    assert all(math.isfinite(c) and abs(c) < 100.0 for p in positions for c in p), 'foreign or NaN telemetry used'
    # the flood held a foreign vehicle's heartbeat (system 42) and frames as our system 1: the bridge refuses to
    # command while they are heard (test_bridge_authority.py), then commands its own vehicle again
    observer.wait_for(lambda: observer.link()[1].get('link_refusal') == '', 'the foreign senders to be gone')
    assert observer.call('arm', SetBool.Request(data=True)).success  # still commanding its own vehicle


def test_ardupilot_over_tcp(graph):
    """ArduPilot SITL's transport: the vehicle listens on TCP, the bridge connects (config/bridge_ardupilot.yaml)."""
    procs, observer = graph
    port = free_udp_port()
    procs.vehicle('ardupilot', f'tcpin:127.0.0.1:{port}')
    observer.wait_for(lambda: f'on tcpin:127.0.0.1:{port}' in procs.log('vehicle'), 'the vehicle to listen')
    procs.bridge(f'tcp:127.0.0.1:{port}', autopilot='ardupilot')
    observer.wait_for(lambda: observer.link()[1].get('mode') == 'LOITER', 'ArduPilot telemetry over TCP')
    assert observer.link()[1]['autopilot'] == 'ArduPilot'
    n = len(observer.odom)
    observer.wait_for(lambda: len(observer.odom) > n + 20, 'odometry over TCP')
    assert abs(observer.position()[2] - 1.0) < 0.1
    result = observer.call('land', Trigger.Request())
    assert result.success and result.message == 'mode LAND: MAV_RESULT_ACCEPTED'
    observer.wait_for(lambda: observer.link()[1].get('armed') == 'False', 'the vehicle to land and disarm')


SETPOINT_RATE_HZ = 50.0
# of SETPOINT_RATE_HZ, measured at the vehicle over 150 setpoints: the setpoints come from this process's thread, and
# at a fresh clone's make test load (~9) they reached the vehicle at 39 Hz (a stopped stream: none)
FULL_RATE = 0.7


def _rate_hz(tap, after_s, n):
    """Setpoints per second at the vehicle over the first n sent after after_s."""
    times = [t for t, _ in tap.setpoints(after_s)][:n]
    return (len(times) - 1) / (times[-1] - times[0])


def test_a_second_local_sender_gets_nothing_and_never_stops_the_setpoints(tmp_path):
    """Another process floods the bridge's udpin port (3,000 random datagrams and a ground station's heartbeat),
    then closes its socket: it receives nothing the bridge sends (pymavlink's udpin answered every sender, and one
    failed send ended the write to all), is reported in diagnostics, and the vehicle keeps receiving setpoints at
    the full rate; the stale action then reaches the vehicle too."""
    with tapped_graph(tmp_path) as (procs, observer, start):
        tap = start('px4')
        bridge = tap.bridge_addr
        publisher = SetpointPublisher(observer, rate_hz=SETPOINT_RATE_HZ)
        try:
            observer.wait_for(lambda: int(observer.setpoints()[1].get('received', 0)) > 20, 'setpoints at the bridge')
            answer = observer.call('offboard', SetBool.Request(data=True))
            assert answer.success, answer.message
            observer.wait_for(lambda: observer.link()[1].get('mode') == 'OFFBOARD', 'mode OFFBOARD')

            sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sender.bind(('127.0.0.1', 0))
            rng, gcs = random.Random(11), mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
            for _ in range(3000):
                sender.sendto(bytes(rng.getrandbits(8) for _ in range(rng.randint(1, 300))), bridge)
            sender.sendto(mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3).pack(gcs), bridge)
            flooded = time.monotonic()
            observer.wait_for(lambda: len(tap.setpoints(flooded)) >= 150, '150 setpoints at the vehicle after it')
            sender.setblocking(False)
            with pytest.raises(BlockingIOError):
                data = sender.recv(65536)
                pytest.fail(f'the second sender received {len(data)} bytes from the bridge')
            address = f'127.0.0.1:{sender.getsockname()[1]}'
            observer.wait_for(lambda: observer.link()[1].get('other_senders_recent') == address,
                              'the second sender reported')
            assert int(observer.link()[1]['other_sender_datagrams']) >= 1   # those the socket's buffer held
            assert _rate_hz(tap, flooded, 150) >= FULL_RATE * SETPOINT_RATE_HZ

            sender.close()   # sends to it would be refused
            closed = time.monotonic()
            observer.wait_for(lambda: len(tap.setpoints(closed)) >= 150, '150 setpoints after the sender closed')
            assert _rate_hz(tap, closed, 150) >= FULL_RATE * SETPOINT_RATE_HZ
            assert observer.link()[1]['mode'] == 'OFFBOARD' and observer.link()[1]['send_errors'] == '0'
            print(f'setpoints at the vehicle: {_rate_hz(tap, flooded, 150):.1f} Hz after the flood, '
                  f'{_rate_hz(tap, closed, 150):.1f} Hz after the sender closed; '
                  f'{observer.link()[1]["other_sender_datagrams"]} datagrams of the other sender read')
        finally:
            publisher.stop()
        observer.wait_for(lambda: observer.link()[1].get('mode') == 'AUTO.LAND', 'the stale action at the vehicle')
