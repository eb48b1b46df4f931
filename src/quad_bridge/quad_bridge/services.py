"""What the bridge's `arm`, `offboard` and `land` services do and answer, and the landing on shutdown (no rclpy:
each returns (success, message) for the node to put in its response).

Any node of the domain may call them (docs/bridge.md, who can command), so each refuses first when no vehicle
may be commanded: no heartbeat yet, a signing problem, the link not up, a refused link (quad_bridge.peers).
offboard(true) hands over: the vehicle's parameters checked, a live external pose (when forwarded) and a live
setpoint stream from setpoint_source, then the pre-stream (PX4) and DO_SET_MODE into the backend's offboard
mode; the hand-over (quad_bridge.handover) follows the ACK. A refused command's answer gives the vehicle's reason:
its STATUSTEXTs since the command.
"""

import time

from quad_bridge.handover import ACTIVE, PRESTREAM, PRESTREAM_S
from quad_bridge.link import LinkState
from quad_bridge.mavlink_client import mavlink, result_name

OFFBOARD_MIN_STREAM_HZ = 5.0  # on the wire over the pre-stream before asking PX4 for OFFBOARD (it needs > 2 Hz)
STATUSTEXT_WAIT_S = 0.5       # a refused command waits this long (wall) for the vehicle to say why (STATUSTEXT)
PRESTREAM_POLL_S = 0.02       # the pre-stream checks this often whether the hand-over ended meanwhile


def not_ready(system, backend, signing_problem: str, link_state: str) -> str:
    """Why no command may go to the vehicle now, or '' (then the link's own refusal decides): no heartbeat yet,
    a signing problem, the link not up."""
    if system is None or backend is None:
        return 'no vehicle heartbeat yet' + (f': {signing_problem}' if signing_problem else '')
    if signing_problem:
        return signing_problem
    if link_state != LinkState.UP:
        return f'link {link_state}'
    return ''


def refused_answer(what: str, result, said: list) -> str:
    """A command's answer text: `what: RESULT`, and what the vehicle said (its STATUSTEXTs) when it refused."""
    message = f'{what}: {result_name(result)}'
    if said:
        message += ': the vehicle says ' + ' / '.join(f'"{t}"' for t in said)
    return message


class BridgeServices:
    def __init__(self, bridge):
        """bridge: the MavlinkBridge (params, vehicle, link, client, commander, streamer, setpoints, geofence,
        external_pose, link_refusal, update_engaged, publish_diagnostics, now_s, log)."""
        self.bridge = bridge
        self.prestream_s = PRESTREAM_S

    def ready(self) -> str:
        """Why no command may go to the vehicle now (not_ready, then a refused link: quad_bridge.peers), or ''."""
        b = self.bridge
        s = b.vehicle.status
        return not_ready(s.system, s.backend, b.client.signing_problem(), b.link.state) or b.link_refusal()

    def answer(self, what, result, sent_ns) -> tuple[bool, str]:
        """The answer to a command sent at sent_ns (wall); refused, with what the vehicle said since in its
        STATUSTEXTs (the autopilots give the reason there, beside the COMMAND_ACK)."""
        success = result == mavlink.MAV_RESULT_ACCEPTED
        said = [] if success or result is None else self.bridge.vehicle.texts.wait_since(sent_ns, STATUSTEXT_WAIT_S)
        return success, refused_answer(what, result, said)

    def arm(self, arm: bool) -> tuple[bool, str]:
        b = self.bridge
        why = self.ready()
        if why:
            return False, why
        with b.vehicle.lock:
            s, active = b.vehicle.status, b.vehicle.handover.active
            reason = s.backend.arm_refusal(s.mode, active) if arm else None
        if reason:
            return False, f'arm refused: {reason}'
        if not arm and active:   # any node of the domain may call this service (docs/bridge.md, who can command)
            return False, ('disarm refused: the vehicle is flying our setpoints; call land first (a disarm in the '
                           'air drops it)')
        sent_ns = time.time_ns()
        return self.answer('arm' if arm else 'disarm', b.commander.arm(arm), sent_ns)

    def offboard(self, engage: bool) -> tuple[bool, str]:
        b = self.bridge
        why = self.ready()
        if why:
            return False, why
        backend = b.vehicle.status.backend
        if not engage:
            return self._leave_offboard(backend)
        check = b.commander.current_check()
        if check.problems:
            return False, 'offboard refused: ' + '; '.join(check.problems)
        if b.external_pose is not None and b.external_pose.check_timeout(time.time_ns()):
            return False, f'offboard refused: external pose {b.external_pose.fault}'
        if not b.streamer.fresh():
            refused = b.setpoints.refused_sources()
            return False, 'no live setpoint stream: publish cmd/attitude_thrust first' + (
                f' (refused, not setpoint_source {b.params["setpoint_source"]}: {refused})' if refused else '')
        target = backend.offboard_mode
        with b.vehicle.lock:
            b.vehicle.handover.request(target, backend.prestream, b.now_s())
        b.geofence.reset()
        b.streamer.kick()
        if backend.prestream:
            refusal = self.prestream()
            if refusal:
                return False, refusal
        sent_ns = time.time_ns()
        result = b.commander.set_mode(target)
        with b.vehicle.lock:
            b.vehicle.handover.acknowledged(result == mavlink.MAV_RESULT_ACCEPTED, result_name(result),
                                            b.now_s(), b.vehicle.status.mode)
        b.update_engaged()
        b.streamer.kick()
        b.publish_diagnostics()
        return self.answer(f'mode {target}', result, sent_ns)

    def _leave_offboard(self, backend) -> tuple[bool, str]:
        """offboard(false): the hand-over ends and the vehicle holds (after land nothing but land)."""
        b = self.bridge
        with b.vehicle.lock:
            b.vehicle.handover.end('offboard false')
            current = b.vehicle.mode_now(b.now_s())
        b.update_engaged()
        if current == backend.land_mode:
            return True, f'vehicle in {current}: nothing commanded'
        mode = backend.hold_mode('hold')
        sent_ns = time.time_ns()
        return self.answer(f'mode {mode}', b.commander.set_mode(mode), sent_ns)

    def prestream(self) -> str:
        """Setpoints on the wire for PRESTREAM_S before the switch (quad_bridge.handover); the reason to refuse
        offboard, or ''. Ends early when the hand-over ended meanwhile (link lost, setpoints stale)."""
        b = self.bridge
        deadline = time.monotonic() + self.prestream_s
        while time.monotonic() < deadline and b.vehicle.handover.phase == PRESTREAM:
            time.sleep(PRESTREAM_POLL_S)
        rate_hz = b.streamer.rate_hz()   # not under vehicle.lock: the streamer takes it under its own lock
        with b.vehicle.lock:
            handover = b.vehicle.handover
            if handover.phase != PRESTREAM:
                return f'offboard refused during the pre-stream: {handover.reason}'
            if rate_hz < OFFBOARD_MIN_STREAM_HZ:
                handover.end(f'the pre-stream did not reach {OFFBOARD_MIN_STREAM_HZ} Hz')
                return f'no live setpoint stream: {rate_hz:.1f} Hz sent'
        return ''

    def land(self) -> tuple[bool, str]:
        b = self.bridge
        why = self.ready()
        if why:
            return False, why
        with b.vehicle.lock:
            b.vehicle.handover.end('land')
        b.update_engaged()
        mode = b.vehicle.status.backend.land_mode
        sent_ns = time.time_ns()
        return self.answer(f'mode {mode}', b.commander.set_mode(mode), sent_ns)

    def land_on_shutdown(self):
        """Shut down (SIGINT, SIGTERM) while the vehicle flies our setpoints: command what `land` commands and wait
        for its ACK (command_timeout_s at most) before the link closes. Left alone, PX4 falls to its offboard-loss
        failsafe after COM_OF_LOSS_T, and ArduPilot flies the last attitude target for GUID_TIMEOUT, then level
        with no climb, drifting. Returns the ACK's result, or None when nothing was commanded."""
        b = self.bridge
        with b.vehicle.lock:
            s, handover = b.vehicle.status, b.vehicle.handover
            flying = s.backend is not None and (handover.phase == ACTIVE or (
                handover.active and s.backend.obeys_setpoints(b.vehicle.mode_now(b.now_s()))))
            if not flying:
                return None
            handover.end('the bridge is shutting down')
        if b.link.state != LinkState.UP:
            b.log.error(f'shutting down with the vehicle in {s.mode} flying our setpoints and the link '
                        f'{b.link.state}: nothing can be commanded (the vehicle\'s own failsafe acts)')
            return None
        mode = s.backend.land_mode
        b.log.warn(f'shutting down with the vehicle flying our setpoints: commanding {mode}')
        result = b.commander.set_mode(mode)
        if result == mavlink.MAV_RESULT_ACCEPTED:
            b.log.info(f'{mode}: {result_name(result)}')
        else:
            b.log.error(f'{mode}: {result_name(result)}')
        return result
