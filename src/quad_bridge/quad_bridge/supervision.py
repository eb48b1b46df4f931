"""What the bridge commands when the setpoint stream goes quiet or a hand-over ends under it, and the levels its
diagnostics report (no rclpy, no link).

A vehicle armed in a mode that obeys SET_ATTITUDE_TARGET keeps flying the last one it got when nothing more comes
(ArduPilot for GUID_TIMEOUT, in GUIDED as in GUIDED_NOGPS; then level with no climb, drifting), so a stale stream,
a link loss that ended a hand-over (once the link is back) and an external pose fault command `stale_action`'s
mode (`stale_action_mode`); nothing can be commanded while the link is not up (the vehicle's own failsafe acts).
"""

from dataclasses import dataclass

from quad_bridge.link import LinkState
from quad_common import diagnostics


def stale_action_mode(backend, armed: bool, mode: str | None, stale_action: str) -> str | None:
    """The mode stale_action commands (backend.hold_mode) when the vehicle is armed in `mode` (the one the bridge
    takes it to be in: quad_bridge.vehicle_state.Vehicle.mode_now) and that mode obeys SET_ATTITUDE_TARGET; else
    None."""
    if backend is None or not armed or not backend.obeys_setpoints(mode):
        return None
    return backend.hold_mode(stale_action)


@dataclass(frozen=True)
class QuietStreamReport:
    """command: the mode to command now (None: nothing); message: the log line; error: its severity (an error
    when the setpoints went stale or a mode is commanded, else an info)."""
    command: str | None
    message: str
    error: bool


def quiet_stream(stale: bool, setpoint_timeout_s: float, mode: str | None, current: str | None,
                 link_state: str) -> QuietStreamReport:
    """Nothing went out for setpoint_timeout_s (stale: and nothing came in either, the hand-over ends). mode:
    stale_action_mode for the vehicle now; current: the mode it is in."""
    obeying = mode is not None
    command = None
    action = f'nothing commanded (vehicle in {current or "?"}, not flying our setpoints)'
    if link_state != LinkState.UP:
        action = (f'nothing can be commanded while the link is {link_state} (the vehicle\'s own failsafe '
                  'acts; the stale action follows when the link returns with it still flying our setpoints)')
    elif obeying:
        command = mode
        action = f'commanding {mode} (the vehicle in {current} keeps flying the last setpoint)'
    what = f'setpoints stale (none for {setpoint_timeout_s} s)' if stale else 'setpoint stream stopped'
    return QuietStreamReport(command, f'{what}: {action}', stale or obeying)


def hand_over_ended_command(mode: str | None, link_state: str) -> str | None:
    """After a fault ended a hand-over (external pose): stale_action's mode, if there is one and the link is up."""
    return mode if mode is not None and link_state == LinkState.UP else None


def link_level(link_state: str, degraded: bool, refused: bool):
    """The link status's level: up OK, or WARN when degraded (a requested telemetry stream missing, the vehicle's
    parameters contradicting ours, another vehicle on the link, realtime scheduling refused, another local
    sender); waiting WARN; lost ERROR; ERROR in any state when no vehicle may be commanded (a refused link, a
    signing problem)."""
    if refused:
        return diagnostics.ERROR
    if link_state == LinkState.UP:
        return diagnostics.WARN if degraded else diagnostics.OK
    return diagnostics.WARN if link_state == LinkState.WAITING else diagnostics.ERROR


def setpoints_level(stale_events: int, geofence_breached: bool, refused_source: int):
    """The setpoints status's level: WARN once a stream went stale, the geofence was breached or setpoints from a
    publisher other than setpoint_source were refused; else OK."""
    return diagnostics.WARN if stale_events or geofence_breached or refused_source else diagnostics.OK
