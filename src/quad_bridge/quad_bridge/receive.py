"""What the bridge does with every MAVLink message its receive thread reads (no rclpy; never waits on an executor):
the link's liveness and packet loss from our vehicle's messages, every sender on the link (quad_bridge.peers), our
vehicle's heartbeat (its system id when target_system is 0, its autopilot's backend, mode and arming, the link up
or back), and our vehicle's telemetry to the publisher. Only a vehicle's heartbeat (not a GCS's) counts, and only
from target_component."""

import threading

from quad_bridge.backend import MAV_MODE_FLAG_SAFETY_ARMED
from quad_bridge.backends import resolve
from quad_bridge.link import is_vehicle_heartbeat


class Receiver:
    def __init__(self, bridge):
        """bridge: the MavlinkBridge (params, vehicle, link, peers, client, telemetry, commander, supervisor,
        update_engaged, publish_diagnostics, now_s, log)."""
        self.bridge = bridge

    def on_mavlink(self, msg):
        """Every message read (a quad_bridge.mavlink_client.Counted where the kind is not decoded)."""
        b = self.bridge
        now, system, component, seq = b.now_s(), msg.get_srcSystem(), msg.get_srcComponent(), msg.get_seq()
        ours = system == b.vehicle.status.system
        if ours and component == b.params['target_component']:
            b.link.message(now, seq)
        heartbeat = msg.get_type() == 'HEARTBEAT'
        b.peers.seen(system, component, seq, now, heartbeat and is_vehicle_heartbeat(msg.type, msg.autopilot))
        if heartbeat:
            self.on_heartbeat(msg)
        elif ours:  # only our vehicle's telemetry is used
            b.telemetry.handle(msg, now)

    def on_heartbeat(self, msg):
        b = self.bridge
        s = b.vehicle.status
        if not is_vehicle_heartbeat(msg.type, msg.autopilot):
            return
        with b.vehicle.lock:
            if s.system is None:
                s.system = msg.get_srcSystem()
            if msg.get_srcSystem() != s.system or msg.get_srcComponent() != b.params['target_component']:
                return
            b.client.answer_only(s.system, msg.get_srcComponent())   # a udpin link answers only its address
            if s.backend is None:
                try:
                    s.backend = resolve(b.params['autopilot'], msg.autopilot)
                except ValueError as exc:
                    b.log.error(str(exc), throttle_duration_sec=5.0)
                    return
                b.telemetry.start(s.backend)
            change, ended = b.vehicle.heartbeat(msg.custom_mode, bool(msg.base_mode & MAV_MODE_FLAG_SAFETY_ARMED),
                                                b.now_s())
        event = b.link.heartbeat(b.now_s())
        if change:
            b.log.info(f'vehicle mode {change}')
        b.update_engaged()   # engaged once a heartbeat shows the mode we asked for
        if ended:
            b.log.warn(ended)
            b.publish_diagnostics()
        if event == 'reconnected':
            b.supervisor.after_link_loss()
        if event:
            b.log.info(f'vehicle {s.system} {event}: {s.backend.name}, mode {s.mode}')
            b.telemetry.link_up()
            self.start_connect()

    def start_connect(self):
        """The link came up: telemetry requests and the parameter read in a worker (they wait for the ACKs and
        PARAM_VALUEs this thread delivers)."""
        b = self.bridge
        threading.Thread(target=b.commander.connect, args=(b.telemetry.streams,), name='on-connect',
                         daemon=True).start()
