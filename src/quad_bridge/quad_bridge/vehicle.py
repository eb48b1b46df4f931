"""What the bridge knows about its vehicle, under one lock: the receive thread writes it, the setpoint path,
services and diagnostics read it. Holds the hand-over state machine too, so that "may a setpoint go out" and
"did the mode change" are decided on one consistent view. No rclpy."""

import threading
from dataclasses import dataclass, field

from quad_bridge.handover import Handover


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
        self.handover = Handover(confirm_timeout_s)

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
            return change, self.handover.heartbeat(mode, armed, was_armed, now_s)

    def may_stream(self) -> bool:
        with self.lock:
            return self.status.backend is not None and self.handover.may_stream(self.status.mode)
