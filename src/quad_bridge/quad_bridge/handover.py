"""The hand-over state machine: when setpoints may reach the vehicle (docs/bridge.md has the diagram).

    IDLE --offboard(true)--> PRESTREAM (backend.prestream: PX4, PRESTREAM_S) --ACK accepted--> ACTIVE
    IDLE --offboard(true)--> SWITCHING (no prestream: ArduPilot) --ACK accepted--> ACTIVE
    PRESTREAM / SWITCHING --ACK refused or none--> IDLE
    ACTIVE --heartbeat shows another mode (after it showed ours) | disarmed | land | offboard(false)
             | setpoints stale | geofence | link lost | shutdown--> IDLE  (the reason is kept for diagnostics)

Setpoints go out only in PRESTREAM, and in ACTIVE while the vehicle is in the mode we asked for (or has not
yet sent the heartbeat that shows the switch the ACK confirmed). The vehicle is `engaged` (flies our setpoints
as far as we know) only once a heartbeat has shown that mode: an ACK says the switch was accepted, the
heartbeat says it happened. Nothing ever returns to ACTIVE without a new `offboard` call: re-arming, a mode
switch back, or fresh setpoints do not resume streaming.
Pure state; the caller serialises calls (the bridge holds its vehicle lock). Times in seconds.
"""

IDLE, PRESTREAM, SWITCHING, ACTIVE = 'idle', 'prestream', 'switching', 'active'
# PX4 switches into OFFBOARD only while its offboard signal is present, i.e. a setpoint arrived within COM_OF_LOSS_T
# (commander's offboardCheck.cpp), and its user guide asks for a stream above 2 Hz before the switch; PX4's own
# offboard examples (px4_ros_com offboard_control.cpp) stream 10 setpoints at 10 Hz, about 1 s, before asking.
# The bridge streams this long before DO_SET_MODE OFFBOARD.
PRESTREAM_S = 1.0


class Handover:
    def __init__(self, confirm_timeout_s: float = 3.0):
        self.confirm_timeout_s = confirm_timeout_s
        self.phase = IDLE
        self.target = None          # the mode we asked for
        self.confirmed = False      # a heartbeat has shown `target` since the ACK
        self.since_s = 0.0
        self.reason = 'no offboard requested'  # why the phase is what it is (diagnostics)
        self.ended = 0              # hand-overs ended (any reason)

    @property
    def active(self) -> bool:
        return self.phase != IDLE

    def request(self, target: str, prestream: bool, now_s: float):
        self.phase = PRESTREAM if prestream else SWITCHING
        self.target, self.confirmed, self.since_s = target, False, now_s
        self.reason = f'offboard requested: {"pre-streaming before " if prestream else "switching to "}{target}'

    @property
    def engaged(self) -> bool:
        """ACTIVE and a heartbeat has shown the mode we asked for."""
        return self.phase == ACTIVE and self.confirmed

    def acknowledged(self, accepted: bool, why: str, now_s: float, mode: str = ''):
        """The DO_SET_MODE into target was answered (why: the result, e.g. MAV_RESULT_DENIED); mode: what the
        vehicle's heartbeat shows now (a heartbeat showing target may have arrived before the ACK was read)."""
        if self.phase not in (PRESTREAM, SWITCHING):
            return
        if accepted:
            self.phase, self.since_s, self.reason = ACTIVE, now_s, f'in {self.target}: streaming'
            self.confirmed = mode == self.target
        else:
            self.end(f'{self.target} refused by the vehicle: {why}')

    def heartbeat(self, mode: str, armed: bool, was_armed: bool, now_s: float) -> str | None:
        """Follows the vehicle's mode and arming; returns the reason when this ends the hand-over."""
        if self.phase != ACTIVE:
            return None
        if mode == self.target:
            self.confirmed = True
        elif self.confirmed:
            return self.end(f'mode changed to {mode} by the pilot or the autopilot')
        elif now_s - self.since_s > self.confirm_timeout_s:
            return self.end(f'the vehicle never reported {self.target} (still {mode})')
        if was_armed and not armed:
            return self.end('vehicle disarmed')
        return None

    def may_stream(self, mode: str) -> bool:
        if self.phase == PRESTREAM:
            return True
        return self.phase == ACTIVE and (mode == self.target or not self.confirmed)

    def end(self, reason: str) -> str | None:
        """Back to IDLE with `reason`; returns it (None when already idle)."""
        if self.phase == IDLE:
            return None
        self.phase, self.confirmed, self.reason = IDLE, False, f'hand-over ended: {reason}'
        self.ended += 1
        return self.reason
