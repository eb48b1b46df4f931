"""The receive thread over a real UDP socket: only the kinds asked for are decoded, every other message still
reaches on_message as its header (Counted), and a corrupted frame is BAD_DATA either way."""

import os
import socket
import threading

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
            batch, drained_s = client._read_batch()
            batches.append(len(batch))
            drained.append(drained_s is not None)
            seqs += [m.get_seq() for m in batch]
        assert seqs == list(range(10))
        assert max(batches) <= 2, batches
        assert not any(drained[:-1]), (batches, drained)
    finally:
        sender.close()
        client.close()
