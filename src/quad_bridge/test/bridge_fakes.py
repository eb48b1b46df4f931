"""A bridge without ROS or a link for the unit tests of its parts (quad_bridge.commands, services, supervision):
the real vehicle state, link state, peers and geofence, a recording MAVLink client and logger."""

import threading
from types import SimpleNamespace

from quad_bridge.backend import BridgeConfig
from quad_bridge.commands import VehicleCommander
from quad_bridge.geofence import Geofence
from quad_bridge.link import LinkState
from quad_bridge.mavlink_client import mavlink
from quad_bridge.peers import LinkPeers
from quad_bridge.services import BridgeServices
from quad_bridge.supervision import Supervisor
from quad_bridge.vehicle_state import Vehicle

PARAMS = {'target_component': 1, 'target_system': 0, 'command_timeout_s': 3.0, 'telemetry_rate_hz': 50.0,
          'vehicle_params': 'check', 'setpoint_source': '/position_controller', 'setpoint_timeout_s': 0.5,
          'stale_action': 'land', 'link_timeout_s': 2.0, 'max_tilt_deg': 35.0}


class Log:
    """A logger (rclpy's calls) keeping (severity, line)."""

    def __init__(self):
        self.lines = []

    def info(self, line, **_):
        self.lines.append(('info', line))

    def warn(self, line, **_):
        self.lines.append(('warn', line))

    def error(self, line, **_):
        self.lines.append(('error', line))


class Client:
    """MavlinkClient's calls: every command_long / send / read_params recorded; the ACK's result from `results`
    (by MAV_CMD), else `result`."""

    def __init__(self, result=mavlink.MAV_RESULT_ACCEPTED, params=None):
        self.result, self.results, self.params = result, {}, params or {}
        self.commands, self.sent, self.reads = [], [], []
        self.signing, self.problem, self.bad_data, self.handler_errors, self.drained_s = False, '', 0, 0, 0.0

    def command_long(self, system, component, command, params, timeout_s):
        self.commands.append((system, component, command, list(params), timeout_s))
        return self.results.get(command, self.result)

    def read_params(self, system, component, names, timeout_s):
        self.reads.append(tuple(names))
        return {n: self.params[n] for n in names if n in self.params}

    def send(self, name, *args):
        self.sent.append((name, args))

    def signing_problem(self):
        return self.problem


class Streamer:
    def __init__(self, fresh=True, rate_hz=50.0):
        self._fresh, self._rate_hz, self.kicks = fresh, rate_hz, 0
        self.received = self.sent_total = self.keepalives = self.superseded = 0

    def fresh(self):
        return self._fresh

    def rate_hz(self):
        return self._rate_hz

    def kick(self):
        self.kicks += 1


def bridge(backend, params=(), client=None, link_up=True, now_s=10.0):
    """A bridge (the attributes services and supervision read) whose vehicle (system 1) beat as `backend`."""
    p = {**PARAMS, **dict(params)}
    b = SimpleNamespace(params=p, vehicle=Vehicle(p['command_timeout_s']), link=LinkState(p['link_timeout_s']),
                        peers=LinkPeers(), client=client or Client(), log=Log(), streamer=Streamer(),
                        geofence=Geofence(False, [-50, -50, -1], [50, 50, 30]), external_pose=None, engaged=None,
                        t0=0.0, engaged_updates=0, diagnostics=0, time=[now_s],
                        context=SimpleNamespace(ok=lambda: True))
    b.now_s = lambda: b.time[0]
    b.vehicle.status.system, b.vehicle.status.backend = 1, backend
    if link_up:
        b.link.heartbeat(b.now_s())
    b.link_refusal = lambda: ''
    b.setpoints = SimpleNamespace(refused_sources=lambda: '')
    b.update_engaged = lambda: setattr(b, 'engaged_updates', b.engaged_updates + 1)
    b.publish_diagnostics = lambda: setattr(b, 'diagnostics', b.diagnostics + 1)
    b.telemetry = SimpleNamespace(streams=None, timesyncs=0)
    b.telemetry.send_timesync = lambda: setattr(b.telemetry, 'timesyncs', b.telemetry.timesyncs + 1)
    b.commander = VehicleCommander(b.client, b.vehicle, p, BridgeConfig(), b.log, b.now_s)
    b.services = BridgeServices(b)
    b.supervisor = Supervisor(b)
    b.stopping = threading.Event()
    return b


def fly(b, mode):
    """The vehicle armed, handed over and flying `mode` (its heartbeat shows it)."""
    s = b.vehicle.status
    s.armed = True
    b.vehicle.handover.request(mode, s.backend.prestream, b.now_s())
    b.vehicle.handover.acknowledged(True, 'MAV_RESULT_ACCEPTED', b.now_s())
    b.vehicle.heartbeat(s.backend.custom_mode(mode), True, b.now_s())
    assert b.vehicle.handover.engaged
