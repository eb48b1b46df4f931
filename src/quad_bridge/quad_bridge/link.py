"""Link bookkeeping that needs no socket: which heartbeat is our vehicle, is the link up, how fast do
setpoints go out. Times are plain seconds from a monotonic clock passed in by the caller."""

import collections
import threading

MAV_AUTOPILOT_INVALID = 8
# MAV_TYPE values that are not a vehicle: GCS 6, onboard controller 18, gimbal 26, ADS-B 27, camera 30,
# charging station 31, FLARM 32, servo 33, ODID 34, battery 36, parachute 37, log 38, OSD 39, IMU 40,
# GPS 41, winch 42, generic 43.
NON_VEHICLE_TYPES = frozenset({6, 18, 26, 27, 30, 31, 32, 33, 34, 36, 37, 38, 39, 40, 41, 42, 43})


def is_vehicle_heartbeat(mav_type: int, autopilot: int) -> bool:
    return autopilot != MAV_AUTOPILOT_INVALID and mav_type not in NON_VEHICLE_TYPES


class LinkState:
    """WAITING (no vehicle heartbeat yet) -> UP -> LOST (nothing from the vehicle for link_timeout_s) -> UP again
    (its heartbeat).

    Alive is decided from the vehicle's own messages as the receive thread read them (message(): every message
    of the vehicle, not only its 1 Hz heartbeat), and a loss only once the receive thread has drained the link
    past the deadline (update()'s drained_s: it found nothing more to read then): a receive thread that is
    behind or starved (a busy companion computer) is no evidence of a silent vehicle.
    Packet loss from the vehicle's MAVLink sequence numbers (SequenceCounter). The receive thread reports, the
    supervisor and diagnostics ask: all under one lock."""

    WAITING, UP, LOST = 'waiting', 'up', 'lost'

    def __init__(self, link_timeout_s: float):
        self.link_timeout_s = link_timeout_s
        self.state = self.WAITING
        self.last_heartbeat_s = None
        self.last_message_s = None
        self.losses = 0
        self.reconnects = 0
        self.sequence = SequenceCounter()
        self._lock = threading.Lock()

    def heartbeat(self, now_s: float) -> str | None:
        """Record a vehicle heartbeat; returns 'connected' / 'reconnected' on a transition."""
        with self._lock:
            self.last_heartbeat_s = now_s
            self.last_message_s = max(now_s, self.last_message_s or now_s)
            if self.state == self.UP:
                return None
            event = 'connected' if self.state == self.WAITING else 'reconnected'
            if self.state == self.LOST:
                self.reconnects += 1
            self.state = self.UP
            return event

    def message(self, now_s: float, seq: int):
        """A message of the vehicle (any kind, its MAVLink sequence number seq) read at now_s."""
        with self._lock:
            self.last_message_s = now_s if self.last_message_s is None else max(now_s, self.last_message_s)
            self.sequence.observe(seq)

    def update(self, now_s: float, drained_s: float = float('inf')) -> str | None:
        """Returns 'lost' once when nothing came from the vehicle for link_timeout_s, and the receive thread had
        read everything the link delivered up to drained_s, itself past that deadline."""
        with self._lock:
            if self.state != self.UP:
                return None
            silent_s = min(now_s, drained_s) - self.last_message_s
            if silent_s > self.link_timeout_s:
                self.state = self.LOST
                self.losses += 1
                return 'lost'
            return None

    def packet_loss_pct(self) -> float:
        with self._lock:
            return self.sequence.loss_pct()


class SequenceCounter:
    """Packet loss of one sender from its MAVLink sequence numbers (seq counts 0..255 per packet it sends): a
    forward step of n + 1 means n lost; a step back ((seq - expected) mod 256 >= 128: a duplicate or a late
    packet) loses nothing and is counted apart. pymavlink's own count (mavfile.packet_loss), which read up to
    35 % on PX4 SIH with none lost at a relay, takes every step back as ~255 lost and sums every sender."""

    def __init__(self):
        self.last = None
        self.received = self.lost = self.reordered = 0

    def observe(self, seq: int):
        self.received += 1
        if self.last is not None:
            gap = (int(seq) - self.last - 1) % 256
            if gap >= 128:
                self.reordered += 1
                return
            self.lost += gap
        self.last = int(seq)

    def loss_pct(self) -> float:
        return 100.0 * self.lost / (self.received + self.lost) if self.received else 0.0


class VehicleAddress:
    """Which address a UDP server link (udpin) answers: only the vehicle's. pymavlink's udpin answers every address
    that ever sent it a datagram, so any local process could receive the vehicle's setpoints and commands, and one
    failed send ended the write for all of them (the vehicle's included). No socket: the receive thread reports
    every datagram (datagram()) and every frame that parsed (frame()), the senders ask for `address`.

    - Before the owner names its vehicle (vehicle = (system, component), from its first heartbeat): the sender of
      the newest valid MAVLink frame (never a sender of garbage), so that what answers that heartbeat reaches it.
    - After: the address the vehicle's valid frames come from. A vehicle frame from another address takes over
      only once the vehicle's address has been silent (no datagram at all) for switch_after_s: a vehicle that
      restarted on a new port is followed, a process sending frames as the vehicle beside it is not answered.
    - Every other address is counted (datagrams, when last heard; the newest max_tracked addresses kept) and
      reported; a failed send is counted with its reason and never raised.

    Times: seconds, one clock for all calls (the datagrams' arrival times)."""

    def __init__(self, switch_after_s: float = 2.0, window_s: float = 10.0, max_tracked: int = 64):
        self.switch_after_s, self.window_s, self.max_tracked = switch_after_s, window_s, max_tracked
        self.vehicle = None          # (system, component): name_vehicle()
        self.address = None          # where every send goes; None: nobody yet
        self.confirmed = False       # address came from the vehicle's own frames
        self._address_of = None      # (system, component) of the frame that set an unconfirmed address
        self.switches = 0            # the vehicle's address changed (a restart on a new port)
        self.send_errors = 0
        self.send_error_last = ''
        self.datagrams_total = 0
        self._forgotten = 0          # datagrams of addresses no longer tracked (never the vehicle's)
        self._senders = collections.OrderedDict()   # address -> [datagrams, last heard s], least recent first
        self._lock = threading.Lock()

    def datagram(self, address, now_s: float):
        """Any datagram read (garbage too)."""
        with self._lock:
            self.datagrams_total += 1
            entry = self._senders.get(address)
            if entry is None:
                entry = self._senders[address] = [0, now_s]
                if len(self._senders) > self.max_tracked:
                    self._forget()
            else:
                self._senders.move_to_end(address)
            entry[0] += 1
            entry[1] = now_s

    def _forget(self):
        for old in self._senders:
            if old != self.address:
                self._forgotten += self._senders.pop(old)[0]
                return

    def name_vehicle(self, system: int, component: int):
        """The owner's vehicle; the address of its frame that was answered before it was named is its own."""
        with self._lock:
            self.vehicle = (system, component)
            if not self.confirmed and self.address is not None and self._address_of == self.vehicle:
                self.confirmed = True

    def frame(self, address, system: int, component: int, now_s: float):
        """A frame that parsed (length and CRC good) from address."""
        if address == self.address and self.confirmed:
            return   # the usual case, without the lock
        with self._lock:
            if self.vehicle is None:
                self.address, self._address_of = address, (system, component)
                return
            if (system, component) != self.vehicle:
                return
            if self.confirmed and address != self.address:
                heard = self._senders.get(self.address)
                if heard is not None and now_s - heard[1] <= self.switch_after_s:
                    return    # the vehicle's address is alive: another sender as the vehicle is not answered
                self.switches += 1
            self.address, self.confirmed = address, True

    def send_failed(self, address, error: OSError):
        with self._lock:
            self.send_errors += 1
            self.send_error_last = f'{_name(address)}: {error}'

    def others(self, now_s: float) -> list:
        """The addresses other than the vehicle's heard within window_s, most recent first."""
        with self._lock:
            return [a for a, (_, t) in reversed(self._senders.items())
                    if a != self.address and t >= now_s - self.window_s]

    def report(self, now_s: float) -> dict:
        """Diagnostics values: the vehicle's address, the other senders (heard within window_s; datagrams of all
        time), send errors."""
        others = self.others(now_s)
        with self._lock:
            vehicle = self._senders.get(self.address, [0])[0] if self.address is not None else 0
            return {'vehicle_address': _name(self.address) if self.confirmed else '',
                    'other_senders': len(others), 'other_senders_recent': ', '.join(map(_name, others[:4])),
                    'other_sender_datagrams': self.datagrams_total - vehicle,
                    'address_switches': self.switches, 'send_errors': self.send_errors,
                    'send_error_last': self.send_error_last}


def _name(address) -> str:
    return '' if address is None else ':'.join(map(str, address))


class RateMeter:
    """Events per second over the last window_s."""

    def __init__(self, window_s: float = 1.0):
        self.window_s = window_s
        self._times = collections.deque()

    def tick(self, now_s: float):
        self._times.append(now_s)
        self._trim(now_s)

    def rate_hz(self, now_s: float) -> float:
        self._trim(now_s)
        return len(self._times) / self.window_s

    def _trim(self, now_s):
        while self._times and self._times[0] < now_s - self.window_s:
            self._times.popleft()
