"""Who else is on the link: a second vehicle with our target's system id, or vehicles of other system
ids. No socket: fed every parsed message with a monotonic time by the receive thread.

Two senders with one (system, component) are found by MAVLink's packet sequence number: each sender counts its
own packets 0..255 (MAVLink 2 header `seq`), so one sender's numbers step forward by 1 (more where packets were
lost). The numbers are followed as up to two runs ("heads"): a packet one to MAX_STEP ahead of the newest head
continues it, one continuing the other head is a switch between two senders (they interleave in bursts, one
switch per burst), anything else starts a new head. A lossy link only starts new heads; a reordered packet
switches back once; two senders switch at every burst, tens of times a second.
"""

import collections
import threading

WINDOW_S = 2.0
MAX_STEP = 8          # a packet this far ahead of a head continues it (up to 7 lost in a row)
SWITCHES_MIN = 10     # switches between two heads within WINDOW_S that mean two senders


class LinkPeers:
    def __init__(self, window_s: float = WINDOW_S):
        self.window_s = window_s
        self._heads = {}                          # (system, component) -> [newest head's seq, other head's]
        self._switches = collections.defaultdict(collections.deque)   # (system, component) -> switch times
        self._vehicles = {}                       # system id -> last vehicle heartbeat time
        self._lock = threading.Lock()             # seen() on the receive thread, the questions on others

    def seen(self, system: int, component: int, seq: int, now_s: float, vehicle_heartbeat: bool = False):
        with self._lock:
            self._seen((system, component), seq, now_s, vehicle_heartbeat)

    def _seen(self, key, seq, now_s, vehicle_heartbeat):
        if vehicle_heartbeat:
            self._vehicles[key[0]] = now_s
        heads = self._heads.setdefault(key, [])
        if heads and 1 <= (seq - heads[0]) % 256 <= MAX_STEP:
            heads[0] = seq
            return
        if len(heads) > 1 and 1 <= (seq - heads[1]) % 256 <= MAX_STEP:
            switches = self._switches[key]
            switches.append(now_s)
            while switches[0] < now_s - self.window_s:
                switches.popleft()
        heads[:] = [seq, *heads[:1]]   # the other head continues, or a new one starts

    def duplicate(self, system, component, now_s: float) -> str:
        """Why two senders seem to share (system, component), or ''."""
        with self._lock:
            switches = sum(t >= now_s - self.window_s for t in self._switches.get((system, component), ()))
        if switches >= SWITCHES_MIN:
            return (f'two vehicles send as system {system} component {component} ({switches} switches between two '
                    f'packet sequences in {self.window_s:g} s): refusing to command; stop one, or give them distinct '
                    'system ids (PX4 MAV_SYS_ID, ArduPilot SYSID_THISMAV) and set target_system')
        return ''

    def other_vehicles(self, system, now_s: float) -> list[int]:
        """System ids of other vehicles whose heartbeat was heard within the window."""
        with self._lock:
            return sorted(s for s, t in self._vehicles.items() if s != system and t >= now_s - self.window_s)

    def refusal(self, system, component, target_fixed: bool, now_s: float) -> str:
        """Why nothing may be commanded on this link now, or '': a duplicate of our target; or other vehicles
        while the target is 'the first heartbeat' (target_system 0), which may have picked the wrong one."""
        if system is None:
            return ''
        with self._lock:   # the usual answer without counting (asked before every setpoint sent)
            if len(self._switches.get((system, component), ())) < SWITCHES_MIN and all(
                    s == system for s in self._vehicles):
                return ''
        why = self.duplicate(system, component, now_s)
        if why:
            return why
        others = self.other_vehicles(system, now_s)
        if others and not target_fixed:
            return (f'vehicles {", ".join(map(str, [system, *others]))} on the link and target_system 0 took the '
                    f'first heartbeat (system {system}): set target_system to the one to fly')
        return ''
