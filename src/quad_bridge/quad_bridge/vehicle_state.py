"""What the bridge knows about its vehicle, under one lock: the receive thread writes it, the setpoint path,
services and diagnostics read it. Holds the hand-over state machine too, so that "may a setpoint go out" and
"did the mode change" are decided on one consistent view. No rclpy."""

import threading
from dataclasses import dataclass, field

from quad_bridge.handover import Handover
from quad_bridge.statustext import StatusTexts


@dataclass
class VehicleStatus:
    system: int | None = None
    backend: object = None            # quad_bridge.backend.Backend once the first heartbeat named it
    custom_mode: int = 0
    mode: str = ''
    armed: bool = False
    prearm_ready: bool | None = None
    state: object = None              # latest quad_common State in ENU/FLU
    params: dict = field(default_factory=dict)  # semantic parameters read from the vehicle
    rtt_ms: float = float('nan')


class Vehicle:
    def __init__(self, confirm_timeout_s: float = 3.0):
        self.lock = threading.RLock()
        self.status = VehicleStatus()
        self.texts = StatusTexts()         # the vehicle's STATUSTEXTs (the receive thread adds, services read)
        self.handover = Handover(confirm_timeout_s)
        self.confirm_timeout_s = confirm_timeout_s
        self.commanded = None        # the mode we last commanded, until a heartbeat shows it
        self.commanded_s = 0.0

    def command_sent(self, mode: str, now_s: float):
        """We sent DO_SET_MODE `mode`: until a heartbeat shows it (or confirm_timeout_s passed, or the vehicle
        refused it) the vehicle is taken to be in it. The vehicle beats at 1 Hz: a heartbeat older than our command
        must not decide what the vehicle flies (it made a stale check command AUTO.LOITER 0.5 s after our land)."""
        self.commanded, self.commanded_s = mode, now_s

    def command_answered(self, mode: str, accepted: bool):
        """The ACK of our DO_SET_MODE `mode`: refused or unanswered, the heartbeat's mode holds again."""
        if not accepted and self.commanded == mode:
            self.commanded = None

    def mode_now(self, now_s: float) -> str:
        """The mode the vehicle is in as far as we know: the one we commanded (pending its heartbeat), else the
        heartbeat's."""
        if self.commanded is not None and now_s - self.commanded_s <= self.confirm_timeout_s:
            return self.commanded
        return self.status.mode

    def snapshot(self) -> VehicleStatus:
        """A copy to read outside the lock."""
        with self.lock:
            s = self.status
            return VehicleStatus(**{k: getattr(s, k) for k in s.__dataclass_fields__})

    def heartbeat(self, custom_mode: int, armed: bool, now_s: float) -> tuple[str | None, str | None]:
        """Records mode and arming; returns (mode change 'A -> B' or None, hand-over end reason or None)."""
        with self.lock:
            s = self.status
            mode = s.backend.mode_name(custom_mode)
            change = f'{s.mode} -> {mode}' if s.mode and mode != s.mode else None
            was_armed = s.armed
            s.custom_mode, s.mode, s.armed = custom_mode, mode, armed
            if mode == self.commanded:
                self.commanded = None
            return change, self.handover.heartbeat(mode, armed, was_armed, now_s)

    def may_stream(self) -> bool:
        with self.lock:
            return self.status.backend is not None and self.handover.may_stream(self.status.mode)
