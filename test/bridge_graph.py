"""The bridge graph tests' own instruments, beside the graph harness they share with the benches
(quad_bringup.emulated.vehicle_graph): a Tap on the wire between vehicle and bridge, a stand-in
controller's SetpointPublisher, the bridge built inside the test process, a tapped graph, and the odometry probe
process (test/odom_probe.py)."""

import collections
import os
import select
import socket
import sys
import threading
import time
from contextlib import contextmanager

import rclpy
from rclpy.parameter import Parameter

from quad_bringup.emulated.vehicle_graph import PORT_TRIES, ROOT, free_udp_port, running_graph, start_bridge
from quad_common.ros.node_main import close_nodes
from quad_common.ros.testing import Spinner

os.environ['MAVLINK20'] = '1'
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402


def start_odom_probe(procs):
    """test/odom_probe.py in the graph: odometry arrivals seen from a process of their own (odom_arrivals)."""
    return procs.start('odom_probe', [str(ROOT / 'test' / 'odom_probe.py'), '--ros-args'])


def odom_arrivals(procs):
    """(arrival_s on CLOCK_MONOTONIC, stamp_s) arrays of what the odom probe has received so far."""
    from odom_probe import read
    return read(procs.log('odom_probe'))


class Tap:
    """UDP relay vehicle <-> bridge on loopback that sees the wire: it records what the bridge sends
    (SET_ATTITUDE_TARGET, COMMAND_LONG, in order), injects a ground station's commands to the vehicle, can
    cut the link, and can hold the vehicle's datagrams back and release them in bursts (as a real link does)."""

    GCS_SYSTEM = 255
    RECORDED = ('SET_ATTITUDE_TARGET', 'COMMAND_LONG', 'ODOMETRY', 'VISION_POSITION_ESTIMATE', 'VISION_SPEED_ESTIMATE')

    def __init__(self, bridge_port):
        self.vehicle_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.vehicle_side.bind(('127.0.0.1', 0))
        self.port = self.vehicle_side.getsockname()[1]
        self.bridge_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.bridge_side.bind(('127.0.0.1', 0))
        self.bridge_addr = ('127.0.0.1', bridge_port)
        self.vehicle_addr = None
        self.cut = threading.Event()
        self.burst_s = 0.0
        self.lock = threading.Lock()
        self.sent = []          # (monotonic time, message) of what the bridge sent, in order
        self.gcs = mavlink.MAVLink(None, srcSystem=self.GCS_SYSTEM, srcComponent=190)
        self._parser = mavlink.MAVLink(None)
        self._parser.robust_parsing = True
        self._vehicle_parser = mavlink.MAVLink(None)
        self._vehicle_parser.robust_parsing = True
        self.from_vehicle = collections.Counter()   # message type -> count, of what the vehicle sent
        self.heartbeats = []    # (monotonic time, custom_mode) of each vehicle HEARTBEAT passed on to the bridge
        self.drop_kinds = set()  # the vehicle's datagrams holding a message of these kinds are dropped (not counted)
        self._held, self._released_s = [], time.monotonic()
        self.running = True
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        while self.running:
            ready, _, _ = select.select([self.vehicle_side, self.bridge_side], [], [], 0.005)
            for sock in ready:
                data, addr = sock.recvfrom(65536)
                if sock is self.vehicle_side:
                    self.vehicle_addr = addr
                    if self.cut.is_set() or not self._count(data):
                        continue
                    if self.burst_s > 0:
                        self._held.append(data)
                    else:
                        self.bridge_side.sendto(data, self.bridge_addr)
                elif self.vehicle_addr and not self.cut.is_set():
                    self._record(data)
                    self.vehicle_side.sendto(data, self.vehicle_addr)
            if self._held and time.monotonic() - self._released_s >= self.burst_s:
                for data in self._held:
                    self.bridge_side.sendto(data, self.bridge_addr)
                self._held.clear()
                self._released_s = time.monotonic()

    def _count(self, data) -> bool:
        """Counts the vehicle's datagram; False: drop it (drop_kinds)."""
        try:
            msgs = self._vehicle_parser.parse_buffer(data) or []
        except Exception:
            return True
        with self.lock:
            if any(m.get_type() in self.drop_kinds for m in msgs):
                return False
            self.from_vehicle.update(m.get_type() for m in msgs)
            now = time.monotonic()
            self.heartbeats += [(now, m.custom_mode) for m in msgs if m.get_type() == 'HEARTBEAT'
                                and m.get_srcComponent() == 1]
        return True

    def heartbeats_since(self, since_s=0.0):
        """(time, custom_mode) of the vehicle heartbeats passed on since since_s."""
        with self.lock:
            return [(t, mode) for t, mode in self.heartbeats if t >= since_s]

    def _record(self, data):
        try:
            msgs = self._parser.parse_buffer(data) or []
        except Exception:
            return
        now = time.monotonic()
        with self.lock:
            self.sent += [(now, m) for m in msgs if m.get_type() in self.RECORDED]

    def sent_of(self, kind, since_s=0.0):
        """(time, message) of each message of this kind the bridge sent since since_s."""
        with self.lock:
            return [(t, m) for t, m in self.sent if m.get_type() == kind and t >= since_s]

    def setpoints(self, since_s=0.0):
        with self.lock:
            return [(t, m) for t, m in self.sent if m.get_type() == 'SET_ATTITUDE_TARGET' and t >= since_s]

    def commands(self):
        with self.lock:
            return [(t, m) for t, m in self.sent if m.get_type() == 'COMMAND_LONG']

    def set_mode_as_gcs(self, main_mode, sub_mode=0):
        """A ground station (system 255) switches the vehicle's mode: MAV_CMD_DO_SET_MODE, custom mode."""
        self.send_as_gcs(mavlink.MAVLink_command_long_message(1, 1, mavlink.MAV_CMD_DO_SET_MODE, 0, 1, main_mode,
                                                              sub_mode, 0, 0, 0, 0))

    def send_as_gcs(self, msg):
        """A MAVLink message from a ground station (system 255) to the vehicle, past a cut too."""
        self.vehicle_side.sendto(msg.pack(self.gcs), self.vehicle_addr)

    def close(self):
        self.running = False
        self.thread.join(timeout=2)
        self.vehicle_side.close()
        self.bridge_side.close()


class SetpointPublisher:
    """Publishes cmd/attitude_thrust at rate_hz from a thread, from a node of its own named `node_name` in the
    observer's namespace (default: the bridge's setpoint_source, a running controller); attitude(q) and force can
    be changed while it runs."""

    def __init__(self, observer, rate_hz=50.0, quaternion=(0.0, 0.0, 0.0, 1.0), force_mps2=9.81,
                 node_name='position_controller'):
        from sensor_msgs.msg import Imu

        from quad_common.conversions import to_quaternion
        self._to_q, self._imu = to_quaternion, Imu
        self.node = rclpy.create_node(node_name, namespace=observer.node.get_namespace(), context=observer.context,
                                      start_parameter_services=False)
        self.pub = self.node.create_publisher(Imu, 'cmd/attitude_thrust', 10)
        self.period_s, self.quaternion, self.force_mps2 = 1.0 / rate_hz, quaternion, force_mps2
        self.count = 0
        self.stop_event = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        while not self.stop_event.wait(self.period_s):
            msg = self._imu()
            msg.orientation = self._to_q(self.quaternion)
            msg.linear_acceleration.z = self.force_mps2
            msg.angular_velocity_covariance[0] = -1.0
            self.pub.publish(msg)
            self.count += 1

    def stop(self):
        self.stop_event.set()
        close_nodes(None, [self.node], threads=[self.thread])


@contextmanager
def bridge_in_this_process(observer, namespace, url, **params):
    """MavlinkBridge built and spun as its main() does (its executor, the GIL switch interval), inside the test
    process so a test can load that executor; yields the node."""
    from quad_bridge import mavlink_bridge_node
    switch = sys.getswitchinterval()
    sys.setswitchinterval(mavlink_bridge_node.GIL_SWITCH_INTERVAL_S)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=observer.context.get_domain_id())
    node = mavlink_bridge_node.MavlinkBridge(context=context, namespace=namespace, parameter_overrides=[
        Parameter(k, value=v) for k, v in {'fcu_url': url, **params}.items()])
    executor = mavlink_bridge_node.make_executor(node)
    executor.add_node(node)
    spinner = Spinner(executor, [node], name='bridge-executor')
    try:
        yield node
    finally:
        try:
            spinner.close()   # the spinning thread joined before the node is destroyed
        finally:
            context.try_shutdown()
            sys.setswitchinterval(switch)




@contextmanager
def tapped_graph(tmp_path):
    """running_graph plus start(flavour, position, extra, **bridge_params): an emulated vehicle and the bridge
    joined through a Tap (the wire seen between them), once the bridge sees the vehicle armed; yields
    (procs, observer, start) and closes every tap."""
    taps = []
    with running_graph(tmp_path) as (procs, observer):
        def start(flavour, position=(0.0, 0.0, 1.0), extra=(), **bridge_params):
            for _ in range(PORT_TRIES):
                bridge_port = free_udp_port()
                tap = Tap(bridge_port)
                taps.append(tap)
                procs.vehicle(flavour, f'udpout:127.0.0.1:{tap.port}', position=position, extra=extra)
                if start_bridge(procs, f'udpin:127.0.0.1:{bridge_port}', **bridge_params) is not None:
                    observer.wait_for(lambda: observer.link()[1].get('armed') == 'True',
                                      'the bridge to see the armed vehicle')
                    return tap
                procs.stop('vehicle')   # its claimed port taken by a process that claims none: new ports
            raise AssertionError(f'the bridge found its port taken {PORT_TRIES} times')
        try:
            yield procs, observer, start
        finally:
            for tap in taps:
                tap.close()
