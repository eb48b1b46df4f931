"""Which telemetry the bridge asks for and uses: per StreamGroup one message set at a time.

On connect the first set of each group is requested (MAV_CMD_SET_MESSAGE_INTERVAL; autopilots stream
nothing they were not asked for). When a message of the requested set has not arrived within grace_s, the
group falls back to its next set (requested then) and says so; when no set is left, the group is reported
missing. Only the chosen set's messages are used (one odometry source at a time, never interleaved).
Pure; times in seconds; the caller serialises calls.
"""


class StreamSelector:
    def __init__(self, groups, grace_s: float = 3.0):
        self.groups = {g.name: g for g in groups}
        self.grace_s = grace_s
        self.choice = {g.name: 0 for g in groups}     # index into options
        self.requested_s = {}                         # group -> when its current set was requested
        self.seen = {}                                # message name -> last arrival (s)
        self.notes = []                               # fallbacks taken, for diagnostics and the log

    def reset(self, now_s: float):
        """(Re)connected: start again from each group's first set."""
        self.choice = {name: 0 for name in self.groups}
        self.requested_s = {name: now_s for name in self.groups}
        self.seen.clear()

    def current(self, group: str) -> tuple:
        g = self.groups[group]
        return g.options[min(self.choice[group], len(g.options) - 1)]

    def uses(self, group: str, message: str) -> bool:
        return message in self.current(group)

    def arrived(self, message: str, now_s: float):
        self.seen[message] = now_s

    def update(self, now_s: float) -> list:
        """Groups whose requested set is overdue move to their next set; returns [(group, message set)] to
        request now."""
        to_request = []
        for name, g in self.groups.items():
            since = self.requested_s.get(name)
            if since is None or now_s - since < self.grace_s:
                continue
            missing = [m for m in self.current(name) if m not in self.seen]
            if missing and self.choice[name] + 1 < len(g.options):
                self.choice[name] += 1
                self.requested_s[name] = now_s
                self.notes.append(f'{name}: {", ".join(missing)} never arrived, using {"+".join(self.current(name))}')
                to_request.append((name, self.current(name)))
        return to_request

    def missing(self, now_s: float) -> list:
        """Requested messages that never arrived within grace_s (after every fallback)."""
        out = []
        for name in self.groups:
            since = self.requested_s.get(name)
            if since is not None and now_s - since >= self.grace_s:
                out += [m for m in self.current(name) if m not in self.seen]
        return out

    def silent(self, now_s: float, timeout_s: float) -> list:
        """Chosen messages that arrived once but not for timeout_s."""
        return [m for name in self.groups for m in self.current(name)
                if m in self.seen and now_s - self.seen[m] > timeout_s]
