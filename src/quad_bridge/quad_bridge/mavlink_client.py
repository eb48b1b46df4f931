"""A pymavlink connection shared by threads: one receive thread, one lock around every send, and
COMMAND_LONG calls that wait for their COMMAND_ACK on an event (never on the socket).

MAVLink 2 is forced: MAVLINK20 must be set before pymavlink's dialect is first imported.
"""

import math
import os
import select
import threading
import time

os.environ['MAVLINK20'] = '1'
from pymavlink import mavutil  # noqa: E402

mavlink = mavutil.mavlink
MAV_COMP_ID_ONBOARD_COMPUTER = 191
URL_PREFIXES = ('udpin:', 'udpout:', 'udp:', 'udpbcast:', 'tcp:', 'tcpin:')


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


class MavlinkClient:
    """on_message(msg) is called from the receive thread for every parsed message (never BAD_DATA)."""

    def __init__(self, url: str, source_system: int, source_component: int, on_message, baud: int = 57600,
                 signing_key: bytes | None = None):
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

    def send(self, name: str, *args):
        """mav.<name>_send(*args) under the send lock (pymavlink's encoder is not thread-safe)."""
        with self._send_lock:
            getattr(self.conn.mav, name + '_send')(*args)

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

    def _receive_loop(self):
        while self._running:
            try:
                msg = self.conn.recv_match(blocking=True, timeout=0.1)
            except Exception:  # a malformed packet or a socket hiccup must not end the loop
                self.handler_errors += 1
                time.sleep(0.01)
                continue
            if msg is None:   # nothing for the whole timeout: everything delivered has been read
                self.drained_s = time.monotonic()
                continue
            if msg.get_type() == 'BAD_DATA':
                self.bad_data += 1
                self.bad_signature += getattr(msg, 'reason', '') == 'Invalid signature'
                continue
            if msg.get_type() == 'COMMAND_ACK':
                with self._acks_lock:
                    waiter = self._acks.get((msg.get_srcSystem(), msg.command))
                if waiter is not None:
                    waiter[1] = msg.result
                    waiter[0].set()
            elif msg.get_type() == 'PARAM_VALUE':
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
            self._note_drained()

    def _note_drained(self):
        """drained_s = now when nothing is waiting to be read (socket and parser); a receive thread that is behind
        leaves it in the past (LinkState decides a loss only past it)."""
        fd = getattr(self.conn, 'fd', None)
        if fd is None or self.conn.mav.buf_len() > 0:
            return
        try:
            readable = select.select([fd], [], [], 0)[0]
        except (OSError, ValueError):
            return
        if not readable:
            self.drained_s = time.monotonic()
