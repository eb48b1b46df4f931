"""The vehicle's STATUSTEXT: chunks joined into one text, kept a while, read back for a refused command's answer.

MAVLink 2 STATUSTEXT carries 50 bytes; a longer text goes out in chunks with one non-zero `id` and `chunk_seq`
0, 1, ..., the last one shorter than 50 bytes (or ending in NUL, which the decoder strips). id 0 is a text of one
message. A chunked text whose last chunk never comes is given as far as it got once PARTIAL_S has passed.
The autopilots say why they refused a command in a STATUSTEXT sent beside the COMMAND_ACK (PX4 'Arming denied:
...', ArduPilot 'PreArm: ...'): `since(t)` gives what arrived after the command went out."""

import threading
import time
from collections import deque

TEXT_BYTES = 50
KEEP_S = 30.0      # texts kept this long (wall) for since()
PARTIAL_S = 0.5    # a chunked text still missing its last chunk after this long is taken as it is


class StatusTexts:
    def __init__(self, keep_s: float = KEEP_S):
        self.keep_ns = int(keep_s * 1e9)
        self._texts = deque()     # (arrival ns of the first chunk, severity, text), complete
        self._partial = {}        # id -> [arrival ns of its first chunk, severity, {chunk_seq: text}]
        self._lock = threading.Condition()

    def add(self, arrival_ns: int, severity: int, text: str, text_id: int = 0, chunk_seq: int = 0) -> str | None:
        """One STATUSTEXT; returns the text it completes (to log once), else None."""
        with self._lock:
            self._expire(arrival_ns)
            if text_id == 0:
                self._texts.append((arrival_ns, severity, text))
                self._lock.notify_all()
                return text
            partial = self._partial.setdefault(text_id, [arrival_ns, severity, {}])
            partial[2][chunk_seq] = text
            if len(text.encode()) >= TEXT_BYTES:
                return None
            del self._partial[text_id]
            whole = ''.join(partial[2][k] for k in sorted(partial[2]))
            self._texts.append((partial[0], partial[1], whole))
            self._lock.notify_all()
            return whole

    def since(self, t_ns: int, now_ns: int) -> list[str]:
        """The texts whose first chunk arrived at or after t_ns, oldest first (a chunked text missing its end
        after PARTIAL_S included as far as it got)."""
        with self._lock:
            self._expire(now_ns)
            return [text for arrived, _, text in self._texts if arrived >= t_ns]

    def wait_since(self, t_ns: int, timeout_s: float, then_s: float = 0.05, clock=time.time_ns) -> list[str]:
        """since(t_ns) once a text has arrived since t_ns and then_s more have passed (an autopilot may say two
        things), or after timeout_s (wall) with none."""
        deadline = time.monotonic() + timeout_s
        with self._lock:
            while not any(arrived >= t_ns for arrived, _, _ in self._texts):
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self._lock.wait(left)
            else:
                self._lock.wait(then_s)
        return self.since(t_ns, clock())

    def _expire(self, now_ns: int):
        for text_id, (first, severity, chunks) in list(self._partial.items()):
            if now_ns - first > PARTIAL_S * 1e9:
                del self._partial[text_id]
                self._texts.append((first, severity, ''.join(chunks[k] for k in sorted(chunks))))
        while self._texts and now_ns - self._texts[0][0] > self.keep_ns:
            self._texts.popleft()
