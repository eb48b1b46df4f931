"""The receive thread over a real UDP socket: only the kinds asked for are decoded, every other message still
reaches on_message as its header (Counted), and a corrupted frame is BAD_DATA either way."""

import os
import socket
import threading
import time

import pytest

os.environ['MAVLINK20'] = '1'
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

from quad_bridge.mavlink_client import Counted, MavlinkClient  # noqa: E402

HANG_GUARD_S = 30.0   # far above a loaded machine's delivery of a few datagrams


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


class Collector:
    def __init__(self, n):
        self.n, self.messages, self.done = n, [], threading.Event()

    def __call__(self, msg):
        self.messages.append(msg)
        if len(self.messages) >= self.n:
            self.done.set()


def _burst(mav):
    """One datagram as ArduPilot sends a tick: heartbeat, attitude, a corrupted attitude, an ack, a position
    (sequence numbers 0..4)."""
    frames = []
    for msg in (mavlink.MAVLink_heartbeat_message(2, 3, 129, 4, 4, 3),
                mavlink.MAVLink_attitude_message(10, 0.1, 0.2, 0.3, 0, 0, 0),
                mavlink.MAVLink_attitude_message(20, 0.1, 0.2, 0.3, 0, 0, 0),
                mavlink.MAVLink_command_ack_message(511, 0),
                mavlink.MAVLink_local_position_ned_message(30, 1.0, 2.0, -3.0, 0, 0, 0)):
        frames.append(bytearray(msg.pack(mav)))
        mav.seq += 1
    frames[2][12] ^= 0xFF   # a payload byte of the second attitude: its CRC no longer matches
    return b''.join(map(bytes, frames))


@pytest.mark.parametrize('junk', [b'', b'\x55\x55'])   # junk first: pymavlink's own parser takes the datagram
@pytest.mark.parametrize('decode', [('HEARTBEAT', 'LOCAL_POSITION_NED'), None])
def test_only_the_kinds_asked_for_are_decoded_and_every_message_is_counted(decode, junk):
    port = _free_port()
    collect = Collector(4)
    client = MavlinkClient(f'udpin:127.0.0.1:{port}', 1, 191, collect, decode=decode)
    client.start()
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        mav = mavlink.MAVLink(None, srcSystem=7, srcComponent=1)
        sender.sendto(junk + _burst(mav), ('127.0.0.1', port))
        assert collect.done.wait(HANG_GUARD_S), f'only {len(collect.messages)} messages handed on'
    finally:
        sender.close()
        client.close()
    kinds = [m.get_type() for m in collect.messages]
    assert kinds == ['HEARTBEAT', 'ATTITUDE', 'COMMAND_ACK', 'LOCAL_POSITION_NED']
    assert client.bad_data == 1 + bool(junk)          # the corrupted attitude (its CRC), and the junk as one
    assert [m.get_seq() for m in collect.messages] == [0, 1, 3, 4]   # seq 2 was the corrupted one
    assert all((m.get_srcSystem(), m.get_srcComponent()) == (7, 1) for m in collect.messages)
    heartbeat, attitude, ack, position = collect.messages
    assert heartbeat.autopilot == 3 and ack.command == 511 and position.z == -3.0   # decoded: the client's own
    if decode is None:
        assert attitude.roll == pytest.approx(0.1)
    else:
        assert isinstance(attitude, Counted) and attitude.get_msgId() == mavlink.MAVLINK_MSG_ID_ATTITUDE


def test_a_backlog_is_read_in_batches_bounded_by_time_and_every_message_still_arrives():
    """After a stall the link holds a backlog: one batch reads only MAX_BATCH_S of it (a clock that advances
    1.5 ms per look: two datagrams), so the setpoint thread gets the interpreter between batches; none is lost,
    in order, and no batch before the last says it drained."""
    import quad_bridge.mavlink_client as mc

    port = _free_port()
    client = MavlinkClient(f'udpin:127.0.0.1:{port}', 1, 191, lambda msg: None, decode=())
    ticks = iter(range(1, 1_000_000))
    client._clock = lambda: next(ticks) * 0.75 * mc.MAX_BATCH_S
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        mav = mavlink.MAVLink(None, srcSystem=7, srcComponent=1)
        for _ in range(10):
            sender.sendto(mavlink.MAVLink_attitude_message(10, 0.1, 0.2, 0.3, 0, 0, 0).pack(mav),
                          ('127.0.0.1', port))
            mav.seq += 1
        batches, seqs, drained = [], [], []
        while len(seqs) < 10 and len(batches) < 1000:   # hang guard: select() waits up to 0.1 s per read
            batch, arrivals, drained_s = client._read_batch()
            assert len(arrivals) == len(batch)
            batches.append(len(batch))
            drained.append(drained_s is not None)
            seqs += [m.get_seq() for m in batch]
        assert seqs == list(range(10))
        assert max(batches) <= 2, batches
        assert not any(drained[:-1]), (batches, drained)
    finally:
        sender.close()
        client.close()


STALL_S = 0.05   # the receive thread held this long: a busy machine's wait for a CPU


def test_a_message_is_handled_with_when_its_datagram_arrived_not_when_the_thread_got_to_it():
    """The receive thread is held in the first message's handler while the second datagram arrives: the second is
    handled STALL_S later, with the kernel's receive time of its datagram (a starved thread's reading
    time would make the vehicle's messages look late to the clock filter and TIMESYNC)."""
    port = _free_port()
    release, first_in, second_in, seen = threading.Event(), threading.Event(), threading.Event(), []

    def on_message(msg):
        seen.append((client.arrival_ns, time.time_ns()))
        if len(seen) == 1:
            first_in.set()
            release.wait(HANG_GUARD_S)
        else:
            second_in.set()

    client = MavlinkClient(f'udpin:127.0.0.1:{port}', 1, 191, on_message, decode=())
    client.start()
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        mav = mavlink.MAVLink(None, srcSystem=7, srcComponent=1)
        before_first = time.time_ns()
        sender.sendto(mavlink.MAVLink_heartbeat_message(2, 12, 129, 0, 4, 3).pack(mav), ('127.0.0.1', port))
        assert first_in.wait(HANG_GUARD_S)
        before = time.time_ns()
        sender.sendto(mavlink.MAVLink_attitude_message(10, 0.1, 0.2, 0.3, 0, 0, 0).pack(mav), ('127.0.0.1', port))
        after = time.time_ns()
        time.sleep(STALL_S)      # the stall itself (what is tested), not a wait for an event
        release.set()
        assert second_in.wait(HANG_GUARD_S)
    finally:
        release.set()
        sender.close()
        client.close()
    (arrival_1, _), (arrival_2, handled_2) = seen
    assert before_first <= arrival_1 <= before
    assert before <= arrival_2 <= after + 2_000_000, (arrival_2 - before, after - before)
    assert handled_2 - arrival_2 >= STALL_S * 1e9 * 0.9


def _value(kind, field, n, k):
    """A distinct, non-zero, representable value of field number k (n elements) of a numeric type."""
    if kind == 'char':
        return f'text{k}'.encode()
    if kind in ('float', 'double'):
        v = [0.5 + k + 0.25 * i for i in range(n or 1)]
    elif kind.startswith('int'):
        v = [-(k + i + 1) for i in range(n or 1)]
    else:
        v = [k + i + 1 for i in range(n or 1)]
    return v if n else v[0]


def _full(name):
    """A message of the dialect with every field set (extensions too): pymavlink packs all of them."""
    cls = getattr(mavlink, f'MAVLink_{name.lower()}_message')
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths))
    return cls(*[_value(t, f, lengths[f], k) for k, (f, t) in enumerate(zip(cls.fieldnames, cls.fieldtypes))])


def _bridge_kinds():
    from quad_bridge.telemetry_publisher import HANDLERS
    return ('HEARTBEAT', 'COMMAND_ACK', *HANDLERS)


def _received(decode, datagrams, n):
    """What a client decoding `decode` hands on for `datagrams` sent to it over UDP (n messages expected)."""
    port = _free_port()
    collect = Collector(n)
    client = MavlinkClient(f'udpin:127.0.0.1:{port}', 1, 191, collect, decode=decode)
    client.start()
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for datagram in datagrams:
            sender.sendto(datagram, ('127.0.0.1', port))
        assert collect.done.wait(HANG_GUARD_S), f'only {len(collect.messages)} of {n} messages handed on'
    finally:
        sender.close()
        client.close()
    return collect.messages, client


@pytest.mark.parametrize('zeros', [False, True])   # True: trailing zero fields, which MAVLink 2 cuts off the wire
def test_every_kind_the_bridge_decodes_has_pymavlinks_values(zeros):
    """The client's own decode (mavlink_client.Decoded) against pymavlink's decode of the same bytes, for every
    kind the bridge decodes: each field by name and value, and the header."""
    from quad_bridge.mavlink_client import Decoded

    mav = mavlink.MAVLink(None, srcSystem=9, srcComponent=1)
    mav.seq = 200
    frames, sent = [], []
    for name in _bridge_kinds():
        msg = _full(name)
        if zeros:
            for field in msg.fieldnames[len(msg.fieldnames) // 2:]:
                value = getattr(msg, field)
                setattr(msg, field, [0 * x for x in value] if isinstance(value, list) else
                        (b'' if isinstance(value, bytes) else 0 * value))
        frames.append(bytes(msg.pack(mav)))
        sent.append(name)
        mav.seq = (mav.seq + 1) % 256
    messages, client = _received(_bridge_kinds(), frames, len(frames))
    assert client.bad_data == 0 and [m.get_type() for m in messages] == sent
    reference = mavlink.MAVLink(None)
    decoded_here = 0
    for frame, msg in zip(frames, messages):
        expected = reference.decode(bytearray(frame))
        decoded_here += isinstance(msg, Decoded)
        for field in expected.get_fieldnames():
            assert getattr(msg, field) == getattr(expected, field), (msg.get_type(), field)
            assert type(getattr(msg, field)) is type(getattr(expected, field)), (msg.get_type(), field)
        assert (msg.get_seq(), msg.get_srcSystem(), msg.get_srcComponent(), msg.get_msgId(), msg.get_signed()) == (
            expected.get_seq(), 9, 1, expected.get_msgId(), False)
    # every kind but those with char fields (PARAM_VALUE and STATUSTEXT: pymavlink makes strings of them)
    assert decoded_here == len([k for k in sent if k != 'STATUSTEXT'])


def test_bad_crc_truncated_frames_garbage_mavlink1_and_signed_frames():
    """Each datagram's frames as the receive thread splits them: a bad CRC and a cut frame are BAD_DATA, garbage
    before a frame is skipped (BAD_DATA) and the frame still read, MAVLink 1 and signed frames go to pymavlink's
    parser; the good frames after each still arrive, with their values."""
    mav = mavlink.MAVLink(None, srcSystem=7, srcComponent=1)

    def frame(msg):
        data = bytearray(msg.pack(mav))
        mav.seq = (mav.seq + 1) % 256
        return data

    def position(x):
        return frame(mavlink.MAVLink_local_position_ned_message(10, x, 2.0, -3.0, 0.1, 0.2, 0.3))

    bad_crc = position(1.0)
    bad_crc[-1] ^= 0x55
    cut = bytes(position(2.0))[:-5]
    mav1 = mavlink.MAVLink(None, srcSystem=7, srcComponent=1)
    mav1.WIRE_PROTOCOL_VERSION = '1.0'
    v1 = mavlink.MAVLink_local_position_ned_message(10, 4.0, 2.0, -3.0, 0, 0, 0).pack(mav1, force_mavlink1=True)
    signer = mavlink.MAVLink(None, srcSystem=7, srcComponent=1)
    signer.signing.secret_key, signer.signing.sign_outgoing, signer.signing.link_id = b'k' * 32, True, 1
    signer.signing.timestamp = 1
    signed = mavlink.MAVLink_local_position_ned_message(10, 5.0, 2.0, -3.0, 0, 0, 0).pack(signer)
    assert v1[0] == 0xFE and signed[2] & 0x01
    datagrams = [bytes(bad_crc) + bytes(position(11.0)),   # a bad CRC, then a good frame in the same datagram
                 cut,                                      # a frame cut short (its datagram ends early)
                 b'\x00\xfd\x13garbage' + bytes(position(12.0)),
                 bytes(v1),
                 bytes(signed),                            # a signed frame on an unsigned link: pymavlink's decode
                 bytes(position(13.0))]
    messages, client = _received(('LOCAL_POSITION_NED',), datagrams, 5)
    xs = [m.x for m in messages]
    assert xs == [11.0, 12.0, 4.0, 5.0, 13.0]
    assert client.bad_data >= 3   # the bad CRC, the cut frame, the garbage
    assert [m.y for m in messages] == [2.0] * 5 and all(m.get_srcSystem() == 7 for m in messages)


def test_a_signing_link_verifies_every_frame():
    """With a key every frame goes through pymavlink's signature check: a frame signed with the key is decoded,
    one signed with another key or unsigned is refused (bad_signature), never decoded here."""
    key = b's' * 32
    port = _free_port()
    collect = Collector(2)
    client = MavlinkClient(f'udpin:127.0.0.1:{port}', 1, 191, collect, decode=('LOCAL_POSITION_NED',),
                           signing_key=key)
    client.start()

    def signed_with(k, x, seq):
        mav = mavlink.MAVLink(None, srcSystem=7, srcComponent=1)
        mav.seq = seq
        if k is not None:
            mav.signing.secret_key, mav.signing.sign_outgoing, mav.signing.link_id = k, True, 0
            mav.signing.timestamp = int((time.time() - 1420070400) * 100000) + seq   # MAVLink 2's: 10 us since 2015
        return bytes(mavlink.MAVLink_local_position_ned_message(10, x, 0, 0, 0, 0, 0).pack(mav))

    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for datagram in (signed_with(key, 1.0, 0), signed_with(b'w' * 32, 2.0, 1), signed_with(None, 3.0, 2),
                         signed_with(key, 4.0, 3)):
            sender.sendto(datagram, ('127.0.0.1', port))
        assert collect.done.wait(HANG_GUARD_S), f'only {len(collect.messages)} messages handed on'
    finally:
        sender.close()
        client.close()
    assert [m.x for m in collect.messages] == [1.0, 4.0]
    assert all(m.get_signed() for m in collect.messages)
    assert client.bad_signature == 2


@pytest.mark.parametrize('args', [
    (1234, 1, 1, 7, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, 0.5),           # rates ignored: trailing zeros cut
    (0xFFFFFFFF, 3, 1, 0, [0.5, -0.5, 0.5, -0.5], 0.1, -0.2, 0.3, 0.0),  # a zero thrust inside the payload
    (0, 0, 0, 0, [0.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, 0.0),              # all zero: one payload byte kept
])
def test_the_setpoint_on_the_wire_is_pymavlinks_bytes(args):
    """MavlinkClient.send_attitude_target puts on the wire exactly the datagram pymavlink's
    set_attitude_target_send does, with the link's sequence numbers shared with every other send."""
    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.bind(('127.0.0.1', 0))
    receiver.settimeout(HANG_GUARD_S)
    client = MavlinkClient(f'udpout:127.0.0.1:{receiver.getsockname()[1]}', 5, 191, lambda msg: None)
    try:
        client.conn.mav.seq = 254
        client.send_attitude_target(*args)
        client.send('set_attitude_target', *args)    # pymavlink's, with the next sequence number
        client.send_attitude_target(*args)           # wraps to 0
        ours, theirs, wrapped = (receiver.recvfrom(4096)[0] for _ in range(3))
    finally:
        client.close()
        receiver.close()
    reference = mavlink.MAVLink(None, srcSystem=5, srcComponent=191)
    reference.seq = 254
    expected = [bytes(mavlink.MAVLink_set_attitude_target_message(*args).pack(reference))]
    for seq in (255, 0):
        reference.seq = seq
        expected.append(bytes(mavlink.MAVLink_set_attitude_target_message(*args).pack(reference)))
    assert [ours, theirs, wrapped] == expected
    assert client.conn.mav.seq == 1 and client.conn.mav.total_packets_sent == 3


def test_a_setpoint_on_a_signing_link_is_signed():
    """With signing_key the setpoint goes through pymavlink's encoder: signed (incompat flag 1, 13-byte
    signature), and a vehicle with the key accepts it."""
    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.bind(('127.0.0.1', 0))
    receiver.settimeout(HANG_GUARD_S)
    key = b'q' * 32
    client = MavlinkClient(f'udpout:127.0.0.1:{receiver.getsockname()[1]}', 5, 191, lambda msg: None,
                           signing_key=key)
    try:
        client.send_attitude_target(1234, 1, 1, 7, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, 0.5)
        datagram = receiver.recvfrom(4096)[0]
    finally:
        client.close()
        receiver.close()
    assert datagram[2] & 0x01 and len(datagram) == datagram[1] + 12 + 13
    vehicle = mavlink.MAVLink(None)
    vehicle.signing.secret_key = key
    msg = vehicle.decode(bytearray(datagram))
    assert msg.get_type() == 'SET_ATTITUDE_TARGET' and msg.get_signed() and msg.thrust == 0.5
