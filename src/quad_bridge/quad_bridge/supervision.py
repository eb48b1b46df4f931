"""What the bridge commands when the setpoint stream goes quiet or a hand-over ends under it, and the levels its
diagnostics report (no rclpy); Supervisor: those reactions and the periodic checks of the supervisor thread.

A vehicle armed in a mode that obeys SET_ATTITUDE_TARGET keeps flying the last one it got when nothing more comes
(ArduPilot for GUID_TIMEOUT, in GUIDED as in GUIDED_NOGPS; then level with no climb, drifting), so a stale stream,
a link loss that ended a hand-over (once the link is back) and an external pose fault command `stale_action`'s
mode (`stale_action_mode`); nothing can be commanded while the link is not up (the vehicle's own failsafe acts).
"""

import math
import time
from dataclasses import dataclass

import numpy as np

from quad_bridge.geofence import BRAKE, BREACH
from quad_bridge.link import LinkState
from quad_bridge.mavlink_client import mavlink
from quad_common import diagnostics

SUPERVISOR_PERIOD_S = 0.05   # the supervisor thread's checks
HEARTBEAT_PERIOD_S = 1.0     # our HEARTBEAT, TIMESYNC and diagnostics


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


class Supervisor:
    """The bridge's reactions to what ends a hand-over under it (a quiet stream, an external pose fault, the link
    back after a loss, the geofence, another vehicle on the link), and its periodic checks (the supervisor thread,
    every SUPERVISOR_PERIOD_S): the link (lost, back), telemetry stream fall-backs, other vehicles on the link, the
    external pose's timeout, our heartbeat and TIMESYNC (1 Hz) and the diagnostics with them."""

    def __init__(self, bridge):
        """bridge: the MavlinkBridge (params, vehicle, link, client, commander, telemetry, streamer, geofence,
        external_pose, engaged, t0, link_refusal, update_engaged, publish_diagnostics, now_s, log)."""
        self.bridge = bridge
        self.stale_events = 0                 # quiet streams with stale setpoints, link returns that commanded
        self.lost_while_handed_over = False   # a link loss ended a hand-over (after_link_loss)
        self.external_pose_faults = 0         # hand-overs ended by an external pose fault
        self.next_beat_s = 0.0

    def stale_action_mode(self) -> str | None:
        """stale_action_mode for the vehicle now: the mode is the one we commanded while its heartbeat is pending
        (after our own land, nothing but land). Under the vehicle lock."""
        b = self.bridge
        s = b.vehicle.status
        return stale_action_mode(s.backend, s.armed, b.vehicle.mode_now(b.now_s()), b.params['stale_action'])

    def on_stream_quiet(self, wire_age_s, input_age_s):
        """Nothing went out for setpoint_timeout_s: a vehicle in a mode that obeys SET_ATTITUDE_TARGET keeps flying
        the last one (ArduPilot for GUID_TIMEOUT, in GUIDED as in GUIDED_NOGPS), so command stale_action."""
        b = self.bridge
        stale = input_age_s > b.params['setpoint_timeout_s']
        with b.vehicle.lock:
            if stale:
                self.stale_events += 1
                b.vehicle.handover.end(f'setpoints stale (none for {b.params["setpoint_timeout_s"]} s)')
            mode, current = self.stale_action_mode(), b.vehicle.mode_now(b.now_s())
        b.update_engaged()
        report = quiet_stream(stale, b.params['setpoint_timeout_s'], mode, current, b.link.state)
        if report.command is not None:
            b.commander.set_mode(report.command, wait=False)
        if report.error:   # one severity per call site: rclpy refuses a site that changes it
            b.log.error(report.message)
        else:
            b.log.info(report.message)
        b.publish_diagnostics()

    def on_external_pose_fault(self, fault):
        """While the vehicle flies our setpoints on an estimate fed by the external pose, a fault (timeout, jump,
        late) ends the hand-over and commands stale_action: the estimate would drift or jump under it."""
        b = self.bridge
        why = f'external pose: {fault}'
        with b.vehicle.lock:
            ended = b.vehicle.handover.end(why)
            mode = self.stale_action_mode() if ended else None
        if not ended:
            return
        self.external_pose_faults += 1
        b.update_engaged()
        command = hand_over_ended_command(mode, b.link.state)
        if command is not None:
            b.commander.set_mode(command, wait=False)
        b.log.error(f'{why}: hand-over ended' + (f', commanding {mode}' if mode else ''))
        b.publish_diagnostics()

    def after_link_loss(self):
        """The link is back after a loss that ended a hand-over: a vehicle still armed in a mode that obeys
        SET_ATTITUDE_TARGET keeps flying the last one it got (ArduPilot: for GUID_TIMEOUT, then level with no
        climb, drifting) and nothing streams to it any more: the stream is stale, so command stale_action (the
        quiet-stream check may have fired while the link was down, when nothing could be commanded)."""
        b = self.bridge
        with b.vehicle.lock:
            lost, self.lost_while_handed_over = self.lost_while_handed_over, False
            mode = self.stale_action_mode() if lost else None
            current = b.vehicle.mode_now(b.now_s())
            self.stale_events += mode is not None
        if mode is not None:
            b.log.error(f'link back after a loss that ended the hand-over, the vehicle still in {current} '
                        f'flying our last setpoint: commanding {mode}')
            b.commander.set_mode(mode, wait=False)
            b.publish_diagnostics()

    def on_state(self, state):
        """Every odometry state: the geofence (quad_bridge.geofence: braking setpoints before the wall, then land)."""
        b = self.bridge
        if not b.geofence.enabled:
            return
        action = b.geofence.update(state.position, state.velocity, b.vehicle.status.armed, bool(b.engaged),
                                   math.radians(b.params['max_tilt_deg']))
        if action == BRAKE:
            b.log.error(f'geofence ahead: braking at {np.round(state.position, 2).tolist()}, '
                        f'{np.linalg.norm(state.velocity):.2f} m/s')
            b.streamer.kick()   # the braking setpoint (quad_bridge.setpoint_path) on the wire now
        elif action == BREACH:
            with b.vehicle.lock:
                b.vehicle.handover.end(f'geofence: {b.geofence.breach_reason}')
            b.update_engaged()
            where = np.round(state.position, 2).tolist()
            b.log.error(f'geofence: {b.geofence.breach_reason} at {where}: streaming stopped, landing')
            b.commander.set_mode(b.vehicle.status.backend.land_mode, wait=False)

    def check_link_peers(self):
        """A second vehicle as our target, or an ambiguous target: the hand-over ends."""
        b = self.bridge
        why = b.link_refusal()
        if why:
            with b.vehicle.lock:
                ended = b.vehicle.handover.end(why)
            if ended:
                b.log.error(why)
                b.publish_diagnostics()

    def run(self, stopping):
        """The supervisor thread: tick every SUPERVISOR_PERIOD_S until `stopping` is set; an error is logged
        (throttled), never the end of the thread."""
        while not stopping.wait(SUPERVISOR_PERIOD_S):
            try:
                self.tick(self.bridge.now_s())
            except Exception as exc:  # never let the supervisor die silently
                if not self.bridge.context.ok():   # rclpy shut down (Ctrl-C): the node is stopping
                    return
                self.bridge.log.error(f'supervisor: {exc!r}', throttle_duration_sec=1.0)

    def tick(self, now):
        b = self.bridge
        b.update_engaged()
        if b.link.update(now, b.client.drained_s - b.t0) == 'lost':
            with b.vehicle.lock:
                if b.vehicle.handover.end('link lost'):
                    self.lost_while_handed_over = True
            b.log.error(f'vehicle link lost (nothing for {b.params["link_timeout_s"]} s)')
            b.update_engaged()
            b.publish_diagnostics()
        streams = b.telemetry.streams
        if streams is not None and b.link.state == LinkState.UP:
            with b.vehicle.lock:
                fallbacks = streams.update(now)
            for group, messages in fallbacks:
                b.log.warn(streams.notes[-1])
                b.commander.request_messages(messages, b.commander.group_rate_hz(group))
        self.check_link_peers()
        if b.external_pose is not None:
            fault = b.external_pose.check_timeout(time.time_ns())
            if fault and fault.startswith('timeout'):
                self.on_external_pose_fault(fault)
        if now >= self.next_beat_s:
            self.next_beat_s = now + HEARTBEAT_PERIOD_S
            self.heartbeat_tick()

    def heartbeat_tick(self):
        """Our HEARTBEAT (an onboard controller), a TIMESYNC once the vehicle is known, the diagnostics."""
        b = self.bridge
        b.client.send('heartbeat', mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                      mavlink.MAV_STATE_ACTIVE)
        if b.vehicle.status.system is not None:
            b.telemetry.send_timesync()
        b.publish_diagnostics()
