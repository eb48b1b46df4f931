"""Link bookkeeping that needs no socket: which heartbeat is our vehicle, is the link up, how fast do
setpoints go out. Times are plain seconds from a monotonic clock passed in by the caller."""

import collections
import hashlib
import threading

MAV_AUTOPILOT_INVALID = 8
# MAV_TYPE values that are not a vehicle: GCS 6, onboard controller 18, gimbal 26, ADS-B 27, camera 30,
# charging station 31, FLARM 32, servo 33, ODID 34, battery 36, parachute 37, log 38, OSD 39, IMU 40,
# GPS 41, winch 42, generic 43.
NON_VEHICLE_TYPES = frozenset({6, 18, 26, 27, 30, 31, 32, 33, 34, 36, 37, 38, 39, 40, 41, 42, 43})


def is_vehicle_heartbeat(mav_type: int, autopilot: int) -> bool:
    return autopilot != MAV_AUTOPILOT_INVALID and mav_type not in NON_VEHICLE_TYPES


class LinkState:
    """WAITING (no vehicle heartbeat yet) -> UP -> LOST (no heartbeat for link_timeout_s) -> UP again.
    The receive thread reports heartbeats, the supervisor asks for the verdict: both under one lock, so a heartbeat
    that arrives while the verdict is taken is never lost in between."""

    WAITING, UP, LOST = 'waiting', 'up', 'lost'

    def __init__(self, link_timeout_s: float):
        self.link_timeout_s = link_timeout_s
        self.state = self.WAITING
        self.last_heartbeat_s = None
        self.losses = 0
        self.reconnects = 0
        self._lock = threading.Lock()

    def heartbeat(self, now_s: float) -> str | None:
        """Record a vehicle heartbeat; returns 'connected' / 'reconnected' on a transition."""
        with self._lock:
            self.last_heartbeat_s = now_s
            if self.state == self.UP:
                return None
            event = 'connected' if self.state == self.WAITING else 'reconnected'
            if self.state == self.LOST:
                self.reconnects += 1
            self.state = self.UP
            return event

    def update(self, now_s: float) -> str | None:
        """Returns 'lost' once when the last heartbeat is older than link_timeout_s."""
        with self._lock:
            if self.state == self.UP and now_s - self.last_heartbeat_s > self.link_timeout_s:
                self.state = self.LOST
                self.losses += 1
                return 'lost'
            return None


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


def load_signing_key(path: str) -> bytes:
    """32-byte MAVLink 2 signing key from a file: 64 hex characters, else the SHA-256 of the file's text
    (MAVProxy's `signing setup PASSPHRASE` convention)."""
    with open(path, 'rb') as f:
        data = f.read().strip()
    if not data:
        raise ValueError(f'signing_key_file {path!r} is empty')
    try:
        key = bytes.fromhex(data.decode('ascii'))
        if len(key) == 32:
            return key
    except (ValueError, UnicodeDecodeError):
        pass
    return hashlib.sha256(data).digest()
