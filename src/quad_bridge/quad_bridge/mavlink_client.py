"""A pymavlink connection shared by threads: one receive thread, one lock around every send, and
COMMAND_LONG calls that wait for their COMMAND_ACK on an event (never on the socket).

The receive thread reads all the link has delivered before it handles any (one wake-up per burst, not per
message), and decodes only the kinds its owner uses (`decode`): every other message is checked (length, CRC)
and handed on as its header alone (Counted: kind, sender, sequence number), so the link's liveness and packet
counts see every message while the payloads nobody reads are never unpacked. pymavlink's full parse and its
recv_match bookkeeping of every message would dominate the bridge's CPU with an autopilot's real telemetry
(PX4's hundreds of messages/s, ArduPilot's bursts). A signing link decodes everything (pymavlink checks
the signatures).

Each message is handled with the time its bytes arrived (`arrival_ns`, CLOCK_REALTIME ns): on a UDP link the
kernel's receive timestamp of its datagram (SO_TIMESTAMPNS), so a receive thread that waited for a CPU on a busy
machine does not make the vehicle's messages look late to the clock filter and TIMESYNC; on a stream
link the time its chunk was read.

A UDP server link (udpin) answers only its vehicle's address (quad_bridge.link.VehicleAddress, named by the owner
with answer_only()), not pymavlink's set of every address that ever sent a datagram; other senders are counted
(udp_report()). Each datagram is parsed on its own: a partial frame another sender left in the parser is dropped
(BAD_DATA) before the next sender's datagram, so junk can never swallow the vehicle's frames.

MAVLink 2 is forced: MAVLINK20 must be set before pymavlink's dialect is first imported.
"""

import errno
import math
import os
import socket
import struct
import threading
import time

os.environ['MAVLINK20'] = '1'
from pymavlink import mavutil  # noqa: E402

from quad_bridge.link import VehicleAddress  # noqa: E402

mavlink = mavutil.mavlink
MAV_COMP_ID_ONBOARD_COMPUTER = 191
URL_PREFIXES = ('udpin:', 'udpout:', 'udp:', 'udpbcast:', 'tcp:', 'tcpin:')
CLIENT_DECODES = ('COMMAND_ACK', 'PARAM_VALUE')   # the client's own waiters read these
MAX_READS_PER_BATCH = 256     # datagrams (or stream chunks) read before handling them
# Reading (and decoding) stops after this much time even with more queued, the batch is handled and the thread
# gives up the interpreter before the next: after a stall a full batch is many ms of Python in one go,
# which the setpoint thread could take back only at the GIL switch interval.
MAX_BATCH_S = 0.002
MAVLINK2_MAGIC = 0xFD
MAVLINK2_FRAME_BYTES = 12     # header 10 + CRC 2
MAVLINK2_HEADER = struct.Struct('<BBBBBBBHB')   # magic, length, incompat, compat, seq, system, component, id
CRC = struct.Struct('<H')
EXTRA = tuple(bytes((i,)) for i in range(256))   # a CRC_EXTRA byte
UNKNOWN = mavlink.MAVLink_unknown   # a frame of an id the dialect lacks (pymavlink cannot check its CRC)
SO_TIMESTAMPNS = getattr(socket, 'SO_TIMESTAMPNS', 35)   # Linux
TIMESTAMP_SPACE = socket.CMSG_SPACE(16)                   # struct timespec
UDP_MAX_BYTES = 65535


def frame_crc(header_and_payload, crc_extra: int) -> int:
    """MAVLink's CRC (CRC-16/MCRF4XX) of a frame's bytes after the magic and the message's CRC_EXTRA: fastcrc's in
    one call where pymavlink has it (its x25crc object and accumulate per part otherwise)."""
    if _MCRF4XX is not None:
        return _MCRF4XX(bytes(header_and_payload) + EXTRA[crc_extra], 0xFFFF)
    crc = mavlink.x25crc(header_and_payload)
    crc.accumulate(EXTRA[crc_extra])
    return crc.crc


_MCRF4XX = getattr(mavlink, 'mcrf4xx', None)   # pymavlink's own (fastcrc.crc16.mcrf4xx), None without fastcrc


def _timestamps_on(sock) -> bool:
    """Asks the kernel to timestamp every datagram of sock on arrival (False where it cannot)."""
    try:
        sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        return True
    except OSError:
        return False


def check_fcu_url(url: str) -> str | None:
    """The reason `url` is not a pymavlink connection string we accept, or None."""
    if url.startswith(URL_PREFIXES):
        host, _, port = url.split(':', 1)[1].rpartition(':')
        if not host or not port.isdigit() or not 0 <= int(port) <= 65535:
            return f'fcu_url = {url!r} refused: needs HOST:PORT after the scheme'
        return None
    if url.startswith('/dev/') or url.upper().startswith('COM'):
        return None
    return f'fcu_url = {url!r} refused: use udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT or a serial device'


def result_name(result: int | None) -> str:
    if result is None:
        return 'no COMMAND_ACK (timeout)'
    enum = mavlink.enums['MAV_RESULT'].get(result)
    return enum.name if enum else f'MAV_RESULT {result}'


class Counted:
    """A message read and checked but not decoded: what its header says (pymavlink's accessor names)."""

    __slots__ = ('_type', '_id', '_seq', '_system', '_component')

    def __init__(self, kind: str, msg_id: int, seq: int, system: int, component: int):
        self._type, self._id, self._seq, self._system, self._component = kind, msg_id, seq, system, component

    def get_type(self) -> str:
        return self._type

    def get_msgId(self) -> int:
        return self._id

    def get_seq(self) -> int:
        return self._seq

    def get_srcSystem(self) -> int:
        return self._system

    def get_srcComponent(self) -> int:
        return self._component


class Decoded(Counted):
    """A message decoded here, not by pymavlink: its fields as attributes, by pymavlink's names and with pymavlink's
    values (numeric fields; arrays as lists), and pymavlink's accessors (Counted's). For the kinds decoded that have
    no char field: pymavlink's decode (the message object, its header object, the payload and CRC kept) would be the
    larger part of the receive thread's Python per message."""

    __slots__ = ('__dict__',)

    def get_signed(self) -> bool:
        return False

    def __repr__(self):
        return f'{self._type} {self.__dict__}'


class Layout:
    """How one kind's payload decodes: its struct, the full payload size, and each field (declared order) as a
    slice of the unpacked tuple (wire order), exactly as pymavlink's decode orders them."""

    __slots__ = ('kind', 'names', 'unpack', 'size', 'picks', 'plain', 'crc_extra')

    def __init__(self, cls):
        self.kind, self.names, self.crc_extra = cls.msgname, tuple(cls.fieldnames), cls.crc_extra
        self.unpack, self.size = cls.unpacker.unpack_from, cls.unpacker.size
        starts = [sum(cls.lengths[:order]) for order in range(len(cls.lengths))]
        self.picks = tuple((starts[order], cls.lengths[order]) for order in cls.orders)
        self.plain = all(n == 1 for _, n in self.picks) and list(cls.orders) == list(range(len(cls.orders)))

    @staticmethod
    def usable(cls) -> bool:
        """Numeric fields only (char fields are strings in pymavlink's message, which it decodes itself)."""
        return 'char' not in cls.fieldtypes


def decode_payload(layout: Layout, frame, seq: int, system: int, component: int) -> Decoded:
    """The payload of an unsigned MAVLink 2 frame whose length and CRC were checked: zero-padded to the full size
    (MAVLink 2 drops trailing zeros), extensions beyond the dialect's cut off, as pymavlink's decode does."""
    payload = frame[10:-2]
    if len(payload) < layout.size:
        payload = bytes(payload) + bytes(layout.size - len(payload))
    values = layout.unpack(payload)
    msg = Decoded(layout.kind, frame[7] | frame[8] << 8 | frame[9] << 16, seq, system, component)
    if layout.plain:
        msg.__dict__.update(zip(layout.names, values))
    else:
        msg.__dict__.update((name, values[i] if n == 1 else list(values[i:i + n]))
                            for name, (i, n) in zip(layout.names, layout.picks))
    return msg


class MavlinkClient:
    """on_message(msg) is called from the receive thread for every parsed message (never BAD_DATA): a pymavlink
    message for the kinds in `decode` (names; None: every kind), a Counted for the others."""

    def __init__(self, url: str, source_system: int, source_component: int, on_message, baud: int = 57600,
                 signing_key: bytes | None = None, decode=None):
        self.conn = mavutil.mavlink_connection(url, baud=baud, source_system=source_system,
                                               source_component=source_component, autoreconnect=True,
                                               robust_parsing=True)
        if signing_key is not None:
            self.conn.setup_signing(signing_key, sign_outgoing=True)
        self._on_message = on_message
        self._send_lock = threading.Lock()
        self._acks = {}           # (target system, command id) -> [event, result]
        self._acks_lock = threading.Lock()
        self._params = {}         # (target system, parameter name) -> [event, (value, type)]
        self._running = False
        self._thread = None
        self.bad_data = 0         # unparsable bytes / failed CRC
        self.bad_signature = 0    # of those: refused by MAVLink 2 signing (a wrong signature or none)
        self.signing = signing_key is not None
        self.handler_errors = 0   # exceptions from on_message or the parser, survived
        self.drained_s = -math.inf  # monotonic time at which the receive thread had read all the link delivered
        self._decoded_ids = None if decode is None else frozenset(
            getattr(mavlink, f'MAVLINK_MSG_ID_{name}') for name in (*decode, *CLIENT_DECODES))
        # the kinds decoded here (Decoded) rather than by pymavlink: every decoded kind with numeric fields only
        self._layouts = {} if decode is None else {
            i: Layout(mavlink.mavlink_map[i]) for i in self._decoded_ids if Layout.usable(mavlink.mavlink_map[i])}
        self._full_decode = self.conn.mav.decode
        self._datagrams = isinstance(self.conn, mavutil.mavudp)   # whole frames per read (_split)
        self._kernel_stamps = self._datagrams and _timestamps_on(self.conn.port)
        self.arrival_ns = 0       # when the bytes of the message being handled arrived (receive thread)
        self.arrival_address = None   # and from where (UDP; None on other links)
        self._partial_from = None     # the sender whose bytes pymavlink's parser holds (UDP)
        # udpin: only the vehicle's address is answered (pymavlink's write answers every sender)
        self.vehicle_address = VehicleAddress() if self._datagrams and self.conn.udp_server else None
        if self.vehicle_address is not None:
            self.conn.write = self._write_to_vehicle
        self._clock = time.monotonic
        self.conn.mav.decode = self._decode     # pymavlink's parser calls it for every complete frame

    def start(self):
        self._running = True
        self._thread = threading.Thread(target=self._receive_loop, name='mavlink-rx', daemon=True)
        self._thread.start()

    def close(self):
        self._running = False
        if self._thread:
            self._thread.join(timeout=2.0)
        with self._send_lock:
            self.conn.close()

    def answer_only(self, system: int, component: int):
        """The vehicle this link answers (UDP server links): the address its frames come from."""
        if self.vehicle_address is not None:
            self.vehicle_address.name_vehicle(system, component)

    def udp_report(self, now_s: float | None = None) -> dict:
        """quad_bridge.link.VehicleAddress.report (seconds of CLOCK_REALTIME, the datagrams' clock); {} on links
        that are not UDP servers."""
        if self.vehicle_address is None:
            return {}
        return self.vehicle_address.report(time.time() if now_s is None else now_s)

    def _write_to_vehicle(self, buf):
        """pymavlink's mavudp.write for a UDP server link: to the vehicle's address only (nothing before one is
        known); a failed send is counted (VehicleAddress.send_failed), never raised."""
        address = self.vehicle_address.address
        if address is None:
            return
        try:
            self.conn.port.sendto(buf, address)
        except OSError as exc:
            self.vehicle_address.send_failed(address, exc)

    def send(self, name: str, *args):
        """mav.<name>_send(*args) under the send lock (pymavlink's encoder is not thread-safe)."""
        with self._send_lock:
            getattr(self.conn.mav, name + '_send')(*args)

    def send_attitude_target(self, time_boot_ms, target_system, target_component, type_mask, q, roll_rate,
                             pitch_rate, yaw_rate, thrust):
        """SET_ATTITUDE_TARGET, the bytes pymavlink's set_attitude_target_send puts on the wire (MAVLink 2, the
        payload's trailing zeros cut, the same sequence number and counters), without its message object and
        header object: every setpoint goes through here. A signing link, or one with a send callback,
        goes through pymavlink."""
        with self._send_lock:
            mav = self.conn.mav
            cls = mavlink.MAVLink_set_attitude_target_message
            if mav.signing.sign_outgoing or mav.send_callback is not None or mavlink.WIRE_PROTOCOL_VERSION != '2.0':
                mav.set_attitude_target_send(time_boot_ms, target_system, target_component, type_mask, q, roll_rate,
                                             pitch_rate, yaw_rate, thrust)
                return
            payload = cls.unpacker.pack(time_boot_ms, *q, roll_rate, pitch_rate, yaw_rate, thrust, target_system,
                                        target_component, type_mask)
            payload = payload.rstrip(b'\x00') or payload[:1]    # MAVLink 2 truncation (pymavlink keeps one byte)
            frame = MAVLINK2_HEADER.pack(MAVLINK2_MAGIC, len(payload), 0, 0, mav.seq, mav.srcSystem,
                                         mav.srcComponent, cls.id & 0xFFFF, cls.id >> 16) + payload
            frame += CRC.pack(frame_crc(frame[1:], cls.crc_extra))
            self.conn.write(frame)
            mav.seq = (mav.seq + 1) % 256
            mav.total_packets_sent += 1
            mav.total_bytes_sent += len(frame)

    def signing_problem(self) -> str:
        """quad_bridge.signing's verdict on this link's counts, or ''."""
        from quad_bridge.signing import signing_problem
        sig = self.conn.mav.signing
        return signing_problem(self.signing, sig.sig_count, sig.badsig_count, self.bad_signature - sig.badsig_count)

    def command_long(self, target_system, target_component, command, params, timeout_s=None):
        """Sends COMMAND_LONG; with timeout_s, waits for the matching COMMAND_ACK and returns its result
        (None on timeout), resending once halfway (confirmation 1). Without timeout_s returns None at once."""
        params = list(params) + [0.0] * (7 - len(params))
        if timeout_s is None:
            self.send('command_long', target_system, target_component, command, 0, *params)
            return None
        waiter = [threading.Event(), None]
        key = (target_system, command)
        with self._acks_lock:
            self._acks[key] = waiter
        try:
            for confirmation in (0, 1):
                self.send('command_long', target_system, target_component, command, confirmation, *params)
                if waiter[0].wait(timeout_s / 2):
                    return waiter[1]
            return None
        finally:
            with self._acks_lock:
                if self._acks.get(key) is waiter:
                    del self._acks[key]

    def read_params(self, target_system, target_component, names, timeout_s) -> dict:
        """PARAM_REQUEST_READ of each name (by name, index -1), resent once halfway; returns {name: (value,
        param_type)} of those answered by PARAM_VALUE within timeout_s."""
        waiters = {name: [threading.Event(), None] for name in names}
        with self._acks_lock:
            for name, waiter in waiters.items():
                self._params[(target_system, name)] = waiter
        try:
            deadline = time.monotonic() + timeout_s
            for attempt in (0, 1):
                for name, waiter in waiters.items():
                    if not waiter[0].is_set():
                        self.send('param_request_read', target_system, target_component, name.encode(), -1)
                until = deadline - (timeout_s / 2 if attempt == 0 else 0.0)
                for waiter in waiters.values():
                    waiter[0].wait(max(until - time.monotonic(), 0.0))
            return {name: w[1] for name, w in waiters.items() if w[0].is_set()}
        finally:
            with self._acks_lock:
                for name, waiter in waiters.items():
                    if self._params.get((target_system, name)) is waiter:
                        del self._params[(target_system, name)]

    def _decode(self, msgbuf):
        """An unsigned MAVLink 2 frame of the dialect with a good length and CRC: a Decoded for the kinds decoded
        with numeric fields only, a Counted for the kinds not decoded. pymavlink's decode for the rest (a signed
        frame or link, MAVLink 1, the kinds with char fields, an unknown id, a bad length or CRC: its errors are
        BAD_DATA as before)."""
        if self._decoded_ids is None or self.signing or msgbuf[0] != MAVLINK2_MAGIC or msgbuf[2] != 0:
            return self._full_decode(msgbuf)
        msg_id = msgbuf[7] | msgbuf[8] << 8 | msgbuf[9] << 16
        kind = mavlink.mavlink_map.get(msg_id)
        layout = self._layouts.get(msg_id)
        if kind is None or len(msgbuf) != msgbuf[1] + MAVLINK2_FRAME_BYTES or (
                layout is None and msg_id in self._decoded_ids):
            return self._full_decode(msgbuf)
        if frame_crc(msgbuf[1:-2], kind.crc_extra) != (msgbuf[-2] | msgbuf[-1] << 8):
            return self._full_decode(msgbuf)   # raises pymavlink's CRC error: BAD_DATA as before
        if layout is not None:
            return decode_payload(layout, msgbuf, msgbuf[4], msgbuf[5], msgbuf[6])
        return Counted(kind.msgname, msg_id, msgbuf[4], msgbuf[5], msgbuf[6])

    def _split(self, data, batch) -> bytes:
        """A datagram's whole unsigned MAVLink 2 frames into batch without pymavlink's byte-wise parser (a UDP
        datagram holds whole frames); returns what is left for that parser (anything else: MAVLink 1, signed,
        bad flags, junk, a cut frame), from the first such byte on."""
        i, n = 0, len(data)
        while i + MAVLINK2_FRAME_BYTES <= n and data[i] == MAVLINK2_MAGIC and data[i + 2] == 0:
            end = i + data[i + 1] + MAVLINK2_FRAME_BYTES
            if end > n:
                break
            frame = bytearray(data[i:end])
            try:
                batch.append(self._decode(frame))
            except mavlink.MAVError as reason:      # as pymavlink's robust parsing reports it
                batch.append(mavlink.MAVLink_bad_data(frame, reason.message))
            i = end
        return data[i:]

    def _recv(self) -> tuple[bytes, int, tuple | None]:
        """One read of the link, when its bytes arrived and from where: on UDP the kernel's timestamp of the
        datagram and its sender (a broadcast link's sender kept as pymavlink's mavudp.recv does); on other links
        the time of the read and None."""
        conn = self.conn
        if not self._datagrams:
            return conn.recv(), time.time_ns(), None
        try:
            data, ancillary, _, address = conn.port.recvmsg(UDP_MAX_BYTES,
                                                            TIMESTAMP_SPACE if self._kernel_stamps else 0)
        except OSError as exc:
            if exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK, errno.ECONNREFUSED):
                return b'', 0, None
            raise
        if conn.broadcast:
            conn.last_address = address
        arrival_ns = None
        for level, kind, stamp in ancillary:
            if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and len(stamp) >= 16:
                sec, nsec = struct.unpack_from('qq', stamp)
                arrival_ns = sec * 1_000_000_000 + nsec
        arrival_ns = arrival_ns or time.time_ns()
        if self.vehicle_address is not None:
            self.vehicle_address.datagram(address, arrival_ns * 1e-9)
        return data, arrival_ns, address

    def _drop_partial(self, address, batch):
        """A datagram from another sender than the one whose partial frame pymavlink's parser holds: that
        partial is dropped as BAD_DATA (MAVLink over UDP sends whole frames; another sender's bytes would only be
        read as its continuation, and a junk header claiming 255 bytes swallowed the vehicle's next datagrams)."""
        mav = self.conn.mav
        if mav.buf_len() and address != self._partial_from:
            batch.append(mavlink.MAVLink_bad_data(bytes(mav.buf[mav.buf_index:]), 'frame cut at the end of a '
                                                                                  'datagram'))
            mav.buf, mav.buf_index, mav.expected_length = bytearray(), 0, mavlink.HEADER_LEN_V1 + 2

    def _read_batch(self) -> tuple[list, list, float | None]:
        """The messages the link has delivered (waiting up to 0.1 s for the first; at most MAX_READS_PER_BATCH
        reads or MAX_BATCH_S of reading), when each one's bytes arrived (ns, CLOCK_REALTIME) and from where (UDP's
        sender address, else None) as pairs, and the monotonic
        time at which a read found nothing more and the parser held no partial frame (None: not drained)."""
        conn = self.conn
        if not conn.select(0.1):
            return [], [], time.monotonic() if conn.mav.buf_len() == 0 else None
        batch, arrivals = [], []
        until = self._clock() + MAX_BATCH_S
        for _ in range(MAX_READS_PER_BATCH):
            if batch and self._clock() >= until:
                return batch, arrivals, None
            data, arrival_ns, address = self._recv()
            received = data
            if self._datagrams and data:
                self._drop_partial(address, batch)
            if self._datagrams and data and conn.mav.buf_len() == 0:
                data = self._split(data, batch)   # what is left for the parser: b'' after whole frames
                if data:
                    batch += conn.mav.parse_buffer(data) or []
            else:
                batch += conn.mav.parse_buffer(data) or []   # a parse of nothing still yields what the parser held
            if self._datagrams and data:
                self._partial_from = address
            arrivals += [(arrival_ns or time.time_ns(), address)] * (len(batch) - len(arrivals))
            if not received:   # the read, not what _split left (that ended every batch after one datagram)
                return batch, arrivals, time.monotonic() if conn.mav.buf_len() == 0 else None
            if getattr(conn, 'fd', None) is None:   # nothing to poll (select only slept): one read per wake-up
                return batch, arrivals, None
        return batch, arrivals, None

    def _receive_loop(self):
        while self._running:
            try:
                batch, arrivals, drained_s = self._read_batch()
            except Exception:  # a malformed packet or a socket hiccup must not end the loop
                self.handler_errors += 1
                time.sleep(0.01)
                continue
            for msg, (self.arrival_ns, self.arrival_address) in zip(batch, arrivals):
                self._handle(msg)
            if drained_s is not None:   # read at drained_s: everything delivered up to then is handled now
                self.drained_s = drained_s
            else:
                time.sleep(0)   # more queued: a thread waiting for the interpreter (setpoints) runs first

    def _handle(self, msg):
        kind = msg.get_type()
        if kind == 'BAD_DATA':
            self.bad_data += 1
            self.bad_signature += getattr(msg, 'reason', '') == 'Invalid signature'
            return
        if msg.__class__ is not Counted and msg.get_signed():
            self.conn.post_message(msg)    # of pymavlink's bookkeeping the bridge needs only the signing link id
        if self.vehicle_address is not None and msg.__class__ is not UNKNOWN:
            # before the handler: what answers this message must reach its sender (an unknown id's CRC cannot be
            # checked: junk parses as one)
            self.vehicle_address.frame(self.arrival_address, msg.get_srcSystem(), msg.get_srcComponent(),
                                       self.arrival_ns * 1e-9)
        if kind == 'COMMAND_ACK':
            with self._acks_lock:
                waiter = self._acks.get((msg.get_srcSystem(), msg.command))
            if waiter is not None:
                waiter[1] = msg.result
                waiter[0].set()
        elif kind == 'PARAM_VALUE':
            name = msg.param_id.rstrip('\x00') if isinstance(msg.param_id, str) else msg.param_id
            with self._acks_lock:
                waiter = self._params.get((msg.get_srcSystem(), name))
            if waiter is not None:
                waiter[1] = (msg.param_value, msg.param_type)
                waiter[0].set()
        try:
            self._on_message(msg)
        except Exception:
            self.handler_errors += 1
