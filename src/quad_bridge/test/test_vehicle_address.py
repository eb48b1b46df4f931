"""A udpin link answers only its vehicle: quad_bridge.link.VehicleAddress (pure), and MavlinkClient over real UDP
sockets with a second local sender (garbage, frames as another system and as the vehicle, a closed socket)."""

import errno
import os
import random
import socket
import threading

os.environ['MAVLINK20'] = '1'
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

from quad_bridge.link import VehicleAddress  # noqa: E402
from quad_bridge.mavlink_client import MavlinkClient  # noqa: E402

HANG_GUARD_S = 30.0
VEHICLE, OTHER, NEW_PORT = ('127.0.0.1', 5000), ('127.0.0.1', 6000), ('127.0.0.1', 5001)


def test_before_the_vehicle_is_named_the_newest_valid_frame_is_answered_never_garbage():
    a = VehicleAddress()
    a.datagram(OTHER, 0.0)          # garbage: read, never parsed
    assert a.address is None
    a.datagram(VEHICLE, 0.1)
    a.frame(VEHICLE, 1, 1, 0.1)     # the vehicle's first heartbeat: what answers it must reach it
    assert a.address == VEHICLE and a.report(0.1)['vehicle_address'] == ''   # not confirmed yet
    a.name_vehicle(1, 1)            # that heartbeat was the vehicle's: its address is confirmed
    a.datagram(OTHER, 0.2)
    a.frame(OTHER, 1, 1, 0.2)       # a frame as the vehicle from elsewhere does not take it
    assert a.address == VEHICLE and a.report(0.2)['vehicle_address'] == '127.0.0.1:5000'


def test_only_the_vehicles_frames_move_the_address_and_not_while_it_is_alive():
    a = VehicleAddress(switch_after_s=2.0)
    a.name_vehicle(1, 1)
    a.datagram(OTHER, 0.0)
    a.frame(OTHER, 42, 1, 0.0)      # another system
    assert a.address is None
    a.datagram(VEHICLE, 0.1)
    a.frame(VEHICLE, 1, 1, 0.1)
    assert a.address == VEHICLE
    for t in (0.5, 1.0, 1.5, 2.0):  # a process sending as the vehicle beside it, the vehicle alive
        a.datagram(OTHER, t)
        a.frame(OTHER, 1, 1, t)
        a.datagram(VEHICLE, t)
        assert a.address == VEHICLE
    a.datagram(NEW_PORT, 4.1)       # the vehicle restarted on a new port: its old address silent 2.1 s
    a.frame(NEW_PORT, 1, 1, 4.1)
    assert a.address == NEW_PORT and a.switches == 1
    report = a.report(4.1)
    assert report['vehicle_address'] == '127.0.0.1:5001'
    assert report['other_senders'] == 2 and report['other_senders_recent'].startswith('127.0.0.1:5000')
    assert report['other_sender_datagrams'] == 10   # OTHER's 5 and the old vehicle address's 5


def test_other_senders_are_counted_within_a_window_and_bounded():
    a = VehicleAddress(window_s=10.0, max_tracked=8)
    a.name_vehicle(1, 1)
    a.datagram(VEHICLE, 0.0)
    a.frame(VEHICLE, 1, 1, 0.0)
    for port in range(100):        # a flood from 100 sockets
        a.datagram(('127.0.0.1', 7000 + port), 1.0)
    a.datagram(VEHICLE, 1.0)
    report = a.report(1.0)
    assert report['other_senders'] == 7 and report['other_sender_datagrams'] == 100   # the vehicle's kept
    assert a.address == VEHICLE
    assert a.report(20.0)['other_senders'] == 0   # none heard within the window
    a.send_failed(VEHICLE, ConnectionRefusedError(errno.ECONNREFUSED, 'Connection refused'))
    assert a.report(20.0)['send_errors'] == 1 and '127.0.0.1:5000' in a.report(20.0)['send_error_last']


def _socket():
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(('127.0.0.1', 0))
    s.settimeout(HANG_GUARD_S)
    return s


def _heartbeat(mav):
    frame = mavlink.MAVLink_heartbeat_message(2, 12, 129, 0, 4, 3).pack(mav)
    mav.seq = (mav.seq + 1) % 256
    return frame


def _received(sock) -> list:
    """Everything queued on sock now (non-blocking)."""
    sock.setblocking(False)
    out = []
    try:
        while True:
            out.append(sock.recv(65536))
    except BlockingIOError:
        return out
    finally:
        sock.settimeout(HANG_GUARD_S)


class Handled:
    """on_message of a client: every message with the address it came from; wait(predicate) on them."""

    def __init__(self):
        self.messages, self.client = [], None
        self.changed = threading.Condition()

    def __call__(self, msg):
        with self.changed:
            self.messages.append((msg, self.client.arrival_address))
            self.changed.notify_all()
        if msg.get_type() == 'HEARTBEAT' and msg.get_srcSystem() == 1:
            self.client.answer_only(1, 1)     # as the bridge does on its vehicle's heartbeat

    def wait(self, predicate, what):
        with self.changed:
            assert self.changed.wait_for(lambda: predicate(self.messages), HANG_GUARD_S), what


def _udpin_client(on_message):
    probe = _socket()
    port = probe.getsockname()[1]
    probe.close()
    client = MavlinkClient(f'udpin:127.0.0.1:{port}', 1, 191, on_message, decode=('HEARTBEAT',))
    on_message.client = client
    client.start()
    return client, ('127.0.0.1', port)


def test_the_client_answers_only_the_vehicle_and_a_closed_sender_never_stops_it():
    """pymavlink's udpin answered every address that sent a datagram (the second sender got the vehicle's
    setpoints); the client answers the vehicle's only, reports the other sender, and keeps sending to the vehicle
    after that sender closed its socket and after a failed send."""
    vehicle, other = _socket(), _socket()
    handled = Handled()
    client, bridge = _udpin_client(handled)
    try:
        rng, foreign = random.Random(3), mavlink.MAVLink(None, srcSystem=42, srcComponent=1)
        for step in range(6):   # garbage in steps the socket's buffer holds, each read once a marker after it is
            for _ in range(50):
                other.sendto(bytes(rng.getrandbits(8) for _ in range(rng.randint(1, 300))), bridge)
            other.sendto(bytes(300), bridge)   # completes any frame the garbage began (280 bytes at most)
            other.sendto(_heartbeat(foreign), bridge)   # another system's heartbeat
            handled.wait(lambda ms, step=step: sum(m.get_srcSystem() == 42 for m, _ in ms) > step, 'the garbage read')
        vehicle.sendto(_heartbeat(mavlink.MAVLink(None, srcSystem=1, srcComponent=1)), bridge)
        handled.wait(lambda ms: any(m.get_srcSystem() == 1 for m, _ in ms), "the vehicle's heartbeat")
        other.sendto(_heartbeat(mavlink.MAVLink(None, srcSystem=1, srcComponent=1)), bridge)   # as the vehicle
        handled.wait(lambda ms: any(m.get_srcSystem() == 1 and a == other.getsockname() for m, a in ms),
                     'the heartbeat as the vehicle from the second sender')
        client.send('heartbeat', 18, 8, 0, 0, 4)
        assert vehicle.recv(65536)[0] == 0xFD
        assert _received(other) == [], 'the second sender got what the bridge sends to its vehicle'
        report = client.udp_report()
        assert report['vehicle_address'] == f'127.0.0.1:{vehicle.getsockname()[1]}'
        assert report['other_senders'] == 1 and report['other_sender_datagrams'] == 313
        assert report['other_senders_recent'] == f'127.0.0.1:{other.getsockname()[1]}'

        other.close()                # sends to it would be refused: none go there
        real_port = client.conn.port
        client.conn.port = refusing = _Refusing(real_port)   # one send fails (ECONNREFUSED)
        client.send('heartbeat', 18, 8, 0, 0, 4)
        client.conn.port = real_port
        for _ in range(50):
            client.send_attitude_target(0, 1, 1, 0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, 0.5)
        assert len([vehicle.recv(65536) for _ in range(50)]) == 50
        assert client.udp_report()['send_errors'] == 1 and refusing.refused == 1
        assert 'Connection refused' in client.udp_report()['send_error_last']
    finally:
        vehicle.close()
        other.close()
        client.close()


class _Refusing:
    """A socket whose next sendto fails with ECONNREFUSED (what a closed peer gives a connected socket)."""

    def __init__(self, sock):
        self.sock, self.refused = sock, 0

    def sendto(self, data, address):
        self.refused += 1
        raise ConnectionRefusedError(errno.ECONNREFUSED, 'Connection refused')

    def __getattr__(self, name):
        return getattr(self.sock, name)


def test_another_senders_cut_frame_never_swallows_the_vehicles_next_datagrams():
    """A junk datagram ending in a MAVLink 2 header that claims 255 bytes: pymavlink's parser held it and read the
    vehicle's next 13 datagrams as its continuation (lost). Each sender's datagram is parsed on its own."""
    junk, vehicle = _socket(), _socket()
    handled = Handled()
    client, bridge = _udpin_client(handled)
    try:
        mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        junk.sendto(b'\x01\x02\xfd\xff', bridge)
        for _ in range(5):
            vehicle.sendto(_heartbeat(mav), bridge)
        handled.wait(lambda ms: len(ms) >= 5, 'five vehicle heartbeats handled')
    finally:
        junk.close()
        vehicle.close()
        client.close()
    assert [m.get_seq() for m, _ in handled.messages] == [0, 1, 2, 3, 4]
    assert client.bad_data == 2   # the junk prefix, then its cut frame
