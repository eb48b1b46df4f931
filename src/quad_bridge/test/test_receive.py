"""What the bridge does with each MAVLink message it reads (quad_bridge.receive.Receiver), with real vehicle and link
state and heartbeats as the autopilots send them."""

from bridge_fakes import bridge

from quad_bridge.backend import MAV_MODE_FLAG_SAFETY_ARMED
from quad_bridge.link import LinkState
from quad_bridge.mavlink_client import mavlink
from quad_bridge.px4 import Px4
from quad_bridge.receive import Receiver


class Message:
    def __init__(self, kind, system=1, component=1, seq=0, **fields):
        self.kind, self.system, self.component, self.seq = kind, system, component, seq
        self.__dict__.update(fields)

    def get_type(self):
        return self.kind

    def get_srcSystem(self):   # noqa: N802 (pymavlink's name)
        return self.system

    def get_srcComponent(self):   # noqa: N802
        return self.component

    def get_seq(self):
        return self.seq


def heartbeat(mode='POSCTL', armed=False, system=1, component=1, seq=0, mav_type=mavlink.MAV_TYPE_QUADROTOR,
              autopilot=mavlink.MAV_AUTOPILOT_PX4):
    return Message('HEARTBEAT', system, component, seq, type=mav_type, autopilot=autopilot,
                   custom_mode=Px4().custom_mode(mode), base_mode=MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)


class Telemetry:
    def __init__(self):
        self.started, self.handled, self.link_ups, self.streams = [], [], 0, None

    def start(self, backend):
        self.started.append(backend.name)

    def handle(self, msg, now):
        self.handled.append(msg.kind)

    def link_up(self):
        self.link_ups += 1


class Client:
    def __init__(self):
        self.answering = None

    def answer_only(self, system, component):
        self.answering = (system, component)


def receiver(target_system=None):
    b = bridge(None, link_up=False)
    b.vehicle.status.system = target_system
    b.params['autopilot'] = 'auto'
    b.telemetry, b.client = Telemetry(), Client()
    b.supervisor.after_link_loss = lambda: b.log.lines.append(('test', 'after_link_loss'))
    r = Receiver(b)
    r.start_connect = lambda: b.log.lines.append(('test', 'connect'))
    return b, r


def test_the_first_vehicle_heartbeat_names_the_vehicle_its_backend_and_brings_the_link_up():
    b, r = receiver()
    r.on_mavlink(heartbeat(system=1, mav_type=mavlink.MAV_TYPE_GCS, autopilot=mavlink.MAV_AUTOPILOT_INVALID))
    assert b.vehicle.status.system is None and b.link.state == LinkState.WAITING   # a GCS is no vehicle
    r.on_mavlink(heartbeat(system=7, mode='POSCTL', armed=True))
    s = b.vehicle.status
    assert (s.system, s.backend.name, s.mode, s.armed) == (7, 'PX4', 'POSCTL', True)
    assert b.link.state == LinkState.UP and b.client.answering == (7, 1) and b.telemetry.started == ['PX4']
    assert b.log.lines[-2:] == [('info', 'vehicle 7 connected: PX4, mode POSCTL'), ('test', 'connect')]
    assert b.telemetry.link_ups == 1


def test_another_component_or_vehicle_is_no_heartbeat_of_ours_and_only_ours_gives_telemetry():
    b, r = receiver(target_system=1)
    r.on_mavlink(heartbeat(component=2))
    r.on_mavlink(heartbeat(system=2))
    assert b.vehicle.status.backend is None and b.link.state == LinkState.WAITING
    r.on_mavlink(Message('ODOMETRY', system=2))
    r.on_mavlink(Message('ODOMETRY', system=1))
    assert b.telemetry.handled == ['ODOMETRY']
    assert b.peers.other_vehicles(1, b.now_s()) == [2]


def test_a_mode_change_is_logged_and_a_return_after_a_loss_runs_after_link_loss():
    b, r = receiver()
    r.on_mavlink(heartbeat(mode='POSCTL'))
    r.on_mavlink(heartbeat(mode='AUTO.LOITER', seq=1))
    assert ('info', 'vehicle mode POSCTL -> AUTO.LOITER') in b.log.lines
    assert b.link.update(b.now_s() + 5.0) == 'lost'
    r.on_mavlink(heartbeat(mode='AUTO.LOITER', seq=2))
    assert b.link.state == LinkState.UP and b.log.lines[-3:] == [
        ('test', 'after_link_loss'), ('info', 'vehicle 1 reconnected: PX4, mode AUTO.LOITER'), ('test', 'connect')]


def test_an_autopilot_without_a_backend_is_refused_with_autopilot_auto():
    b, r = receiver()
    r.on_mavlink(heartbeat(autopilot=mavlink.MAV_AUTOPILOT_GENERIC))
    assert b.vehicle.status.backend is None and b.link.state == LinkState.WAITING
    assert b.log.lines[-1][0] == 'error' and 'autopilot = auto: autopilot 0 has no backend' in b.log.lines[-1][1]
    b.params['autopilot'] = 'px4'                # a named flavour forces its backend
    r.on_mavlink(heartbeat(autopilot=mavlink.MAV_AUTOPILOT_GENERIC))
    assert b.vehicle.status.backend.name == 'PX4' and b.link.state == LinkState.UP


def test_every_message_of_our_vehicles_autopilot_keeps_the_link_alive():
    b, r = receiver()
    r.on_mavlink(heartbeat())
    t0 = b.now_s()
    b.time[0] = t0 + 1.5
    r.on_mavlink(Message('ODOMETRY', seq=1))
    assert b.link.update(t0 + 3.0) is None             # 1.5 s after the odometry, link_timeout_s 2
    b.time[0] = t0 + 3.0
    r.on_mavlink(Message('ODOMETRY', component=2, seq=2))   # another component of the vehicle: not the autopilot
    assert b.link.update(t0 + 3.6) == 'lost'
