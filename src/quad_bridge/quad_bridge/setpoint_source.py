"""Who may command the vehicle (rclpy): each `cmd/attitude_thrust` is taken with its publisher's GID and flown only
when the ROS graph names that publisher's node `setpoint_source` (docs/bridge.md, "Who can command your vehicle").

rclpy 7.1.5's take returns the message info without the publisher's GID, so the take goes through rcl's own
`rcl_take_serialized_message` (quad_common.ros.rcl_serialized.SerializedTake). The graph API
(`get_publishers_info_by_topic`) maps the endpoint GID to its node. Fast DDS discovers an endpoint before its
node's name (the graph says _NODE_NAME_UNKNOWN_ until ros_discovery_info arrives: 0.5-0.7 s after a controller
started on a real vehicle's companion, seconds on a busy machine): such a publisher is neither flown nor refused
but held, its newest setpoint kept, and decided as soon as the graph names it (NAME_WAIT_S at most: then refused).
A node name is claimed, not proven: this
stops any other node of the domain (a test tool, a second controller, a stray script) from flying the vehicle,
never a deliberate impostor; two publishers claiming the name refuse both. Authentication needs SROS2.
"""

import threading
import time
from collections.abc import Callable

from quad_common.ros.rcl_serialized import SerializedTake

GRAPH_REFRESH_MIN_S = 0.1   # a publisher not admitted asks the graph at most this often (an intruder cannot flood it)
NAME_WAIT_S = 5.0           # a publisher the graph does not name is held this long after its first setpoint
HELD_MAX_AGE_S = 0.2        # a held setpoint older than this when its publisher is admitted is not flown (stale)
UNKNOWN_NAME = '_NODE_NAME_UNKNOWN_'
ADMIT, HOLD, REFUSE = 'admit', 'hold', 'refuse'


def fully_qualified(name: str, namespace: str) -> str:
    """`name` as a node's fully qualified name: a relative one is in `namespace` (the bridge's)."""
    if not name or name.startswith('/'):
        return name
    return f'{namespace.rstrip("/")}/{name}'


class SourceGate:
    """Admits a publisher GID when the graph names its node `source` and no other publisher claims that name; holds
    one the graph does not name yet (NAME_WAIT_S at most). publishers() -> [(node fully qualified name, gid bytes)]
    of the topic now; clock() -> monotonic seconds. Pure Python (no rclpy), one caller thread; counts() may be read
    from others."""

    def __init__(self, source: str, publishers: Callable[[], list], clock=time.monotonic):
        self.source, self._publishers, self._clock = source, publishers, clock
        self._names = {}            # gid -> node name, as the graph last said
        self._conflict = ()         # the GIDs of two or more publishers claiming `source`
        self._refreshed_s = -float('inf')
        self._lock = threading.Lock()
        self.admitted = 0
        self.held = 0               # setpoints held while the graph did not name their publisher
        self.refused = {}           # node name (or 'unknown publisher') -> setpoints refused
        self._unnamed_since = {}    # gid -> when its first setpoint came while the graph did not name it

    def admit(self, gid: bytes) -> bool:
        return self.decide(gid) == ADMIT

    def decide(self, gid: bytes) -> str:
        """ADMIT, HOLD (the graph does not name the publisher yet) or REFUSE one setpoint of `gid` (counted)."""
        verdict = self.verdict(gid)
        with self._lock:
            if verdict == ADMIT:
                self.admitted += 1
            elif verdict == HOLD:
                self.held += 1
            else:
                key = self._names.get(gid) or 'unknown publisher'
                self.refused[key] = self.refused.get(key, 0) + 1
        return verdict

    def verdict(self, gid: bytes) -> str:
        """decide's answer, not counted. Anything not admitted asks the graph again (rate-limited)."""
        name = self._names.get(gid)
        if (name != self.source or self._conflict) and self._clock() - self._refreshed_s >= GRAPH_REFRESH_MIN_S:
            self.refresh()
            name = self._names.get(gid)
        if name is None or UNKNOWN_NAME in name:
            first_s = self._unnamed_since.setdefault(gid, self._clock())
            if self._clock() - first_s < NAME_WAIT_S:
                return HOLD
        else:
            self._unnamed_since.pop(gid, None)
        return ADMIT if name == self.source and not self._conflict else REFUSE

    def refresh(self):
        self._refreshed_s = self._clock()
        pubs = self._publishers()
        self._names = {bytes(gid): name for name, gid in pubs}
        claiming = sorted({bytes(gid) for name, gid in pubs if name == self.source})
        self._conflict = tuple(claiming) if len(claiming) > 1 else ()

    def why_refused(self, gid: bytes) -> str:
        name = self._names.get(gid)
        if name == self.source and self._conflict:
            return (f'{len(self._conflict)} publishers claim the node name {self.source}: refusing all of them '
                    '(a duplicate controller or an impostor)')
        who = name or 'a publisher the ROS graph does not name (yet)'
        return f'setpoint from {who} refused: only {self.source} may command the vehicle (setpoint_source)'

    def counts(self) -> dict:
        with self._lock:
            refused = dict(self.refused)
        return {'setpoint_source': self.source, 'refused_source': sum(refused.values()),
                'refused_publishers': ', '.join(f'{n} ({c})' for n, c in sorted(refused.items())),
                'held_unnamed': self.held}


class SetpointSource:
    """The gate on the setpoint subscription of `node`: take(sub) returns the serialized setpoint only when its
    publisher is `source` (refusals counted and logged, throttled); take_one(sub) also says whether one was taken."""

    def __init__(self, node, subscription, source: str, log, clock=time.monotonic, take=None):
        """take(subscription) -> (bytes, gid) or None: SerializedTake (a stand-in in tests)."""
        self.node, self.log, self._clock = node, log, clock
        self._held = {}   # gid -> (newest serialized setpoint, when it was taken) of publishers not yet named
        topic = subscription.topic_name
        self.gate = SourceGate(source, lambda: [(fully_qualified(i.node_name, i.node_namespace), i.endpoint_gid)
                                                for i in node.get_publishers_info_by_topic(topic)],
                               clock=clock)
        self._take = take or SerializedTake()

    def take(self, subscription):
        return self.take_one(subscription)[1]

    def take_one(self, subscription):
        """(a setpoint was taken, its serialized bytes if its publisher is admitted else None)."""
        taken = self._take(subscription)
        if taken is None:
            return False, None
        raw, gid = taken
        verdict = self.gate.decide(gid)
        if verdict == HOLD:
            self._held[gid] = (raw, self._clock())
            return True, None
        self._held.pop(gid, None)   # older than this one
        if verdict == ADMIT:
            return True, raw
        self.log.warn(self.gate.why_refused(gid), throttle_duration_sec=1.0)
        return True, None

    def release(self):
        """The newest held setpoint of a publisher the graph now names `source` (None: none): asked while setpoints
        are held, so a publisher is decided when the graph names it, not only when its next setpoint comes. A held
        setpoint of a publisher named otherwise is dropped (refused), one older than HELD_MAX_AGE_S is dropped."""
        if not self._held:
            return None
        released = None   # at most one publisher is admitted (two claiming the name refuse both)
        for gid, (raw, taken_s) in list(self._held.items()):
            verdict = self.gate.verdict(gid)
            if verdict == HOLD:
                continue
            del self._held[gid]
            if verdict == ADMIT and self._clock() - taken_s <= HELD_MAX_AGE_S:
                released = raw
            elif verdict == REFUSE:
                self.log.warn(self.gate.why_refused(gid), throttle_duration_sec=1.0)
        return released

    def counts(self) -> dict:
        return self.gate.counts()

    def close(self):
        self._take.close()
