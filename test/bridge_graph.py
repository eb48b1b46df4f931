"""Helpers of the bridge graph tests: processes on loopback ports, and an in-process observer node."""

import collections
import fcntl
import itertools
import math
import os
import select
import socket
import subprocess
import sys
import tempfile
import threading
import time
from contextlib import contextmanager
from pathlib import Path

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message
from std_srvs.srv import SetBool, Trigger
from trajectory_msgs.msg import MultiDOFJointTrajectory

from quad_common import contract
from quad_common.conversions import stamp_to_s
from quad_common.node_main import close_nodes
from quad_common.testing import Spinner, isolated_domain

os.environ['MAVLINK20'] = '1'
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
VEHICLE_FILE = str(ROOT / 'config' / 'vehicles' / 'px4_quad.yaml')
WAIT_S = 90.0  # generous: a busy 2-core machine
BRIDGE_DEFAULTS = {}  # parameters every bridge of the graph tests gets unless a test says otherwise
_GRAPHS = itertools.count()


# Ports the tests hand to a process that binds them later (a bridge's udpin, an emulator's tcpin). They lie below
# Fast DDS's (7400 + 250 * domain) and below the kernel's ephemeral range (ip_local_port_range, 32768 and up), so no
# socket gets one unless it names it: a port bound to 0 and closed again could be any process's ephemeral port
# before the test's process binds it. Test processes share them through lock files, held until the process exits.
TEST_PORTS = range(6100, 7400)
_PORT_LOCK_DIR = Path(tempfile.gettempdir()) / 'quadflight-test-ports'
_EPHEMERAL_RANGE = Path('/proc/sys/net/ipv4/ip_local_port_range')
_held_ports = []


def _check_test_ports_outside_ephemeral():
    if _EPHEMERAL_RANGE.is_file():
        low, high = map(int, _EPHEMERAL_RANGE.read_text().split())
        if low <= TEST_PORTS[-1] and TEST_PORTS[0] <= high:
            raise RuntimeError(f'ip_local_port_range {low}-{high} overlaps the test ports '
                               f'{TEST_PORTS[0]}-{TEST_PORTS[-1]} (bridge_graph.TEST_PORTS)')


def free_udp_port() -> int:
    """A loopback port of TEST_PORTS that no other test process has claimed (its lock file, kept until this process
    exits) and that no UDP or TCP socket holds now: for a UDP link, and for vehicle_emu_client's tcpin too."""
    _check_test_ports_outside_ephemeral()
    _PORT_LOCK_DIR.mkdir(exist_ok=True)
    start = os.getpid() * 37 % len(TEST_PORTS)
    for i in range(len(TEST_PORTS)):
        port = TEST_PORTS[(start + i) % len(TEST_PORTS)]
        lock = open(_PORT_LOCK_DIR / f'{port}.lock', 'w')
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            lock.close()
            continue
        if all(_bindable(port, kind) for kind in (socket.SOCK_DGRAM, socket.SOCK_STREAM)):
            _held_ports.append(lock)
            return port
        lock.close()
    raise RuntimeError(f'no free test port in {TEST_PORTS[0]}-{TEST_PORTS[-1]}: too many test processes running')


def _bindable(port, kind) -> bool:
    with socket.socket(socket.AF_INET, kind) as s:
        try:
            s.bind(('127.0.0.1', port))
        except OSError:
            return False
    return True


def python_env(env, src_root: Path | None = None):
    """env with every package of src/ (or of src_root) importable (also without a colcon install)."""
    paths = [str(p) for p in sorted((src_root or ROOT / 'src').iterdir()) if p.is_dir()]
    return dict(env, PYTHONPATH=os.pathsep.join(paths + [env.get('PYTHONPATH', '')]), PYTHONUNBUFFERED='1')


def terminate(proc, timeout_s: float = 20.0):
    """SIGTERM, then SIGKILL if the process has not exited within timeout_s; reaped."""
    proc.terminate()
    try:
        proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


class Processes:
    """Child processes with logs under log_dir; stop() ends each one it started. ROS nodes run in `namespace`,
    so even a stray process left in the same ROS domain by someone else cannot cross-talk with the graph."""

    def __init__(self, env, log_dir: Path, namespace: str, src_root: Path | None = None):
        """src_root: run the packages of another checkout's src/ (bench/bench_bridge_arrival.py's baseline)."""
        self.env, self.log_dir, self.namespace, self.procs = python_env(env, src_root), log_dir, namespace, {}

    def start(self, name, args):
        if '--ros-args' in args:
            args = [*args, '-r', f'__ns:={self.namespace}']
        log = open(self.log_dir / f'{name}.log', 'w')
        self.procs[name] = subprocess.Popen([sys.executable, *args], env=self.env, stdout=log,
                                            stderr=subprocess.STDOUT, cwd=str(ROOT))
        return self.procs[name]

    def stop(self, name):
        terminate(self.procs.pop(name))

    def stop_all(self):
        for name in list(self.procs):
            self.stop(name)

    def log(self, name) -> str:
        return (self.log_dir / f'{name}.log').read_text()

    def vehicle(self, flavour, url, position=(0.0, 0.0, 1.0), name='vehicle', extra=()):
        return self.start(name, ['-m', 'quad_vehicle_emu.mavlink_vehicle', '--autopilot', flavour, '--url', url,
                                 '--vehicle', VEHICLE_FILE, '--initial-position', ','.join(map(str, position)),
                                 *EMULATOR_SCHEDULING, *extra])

    def params_file(self, node, *files) -> str:
        """The `node` section of YAML params files (later ones win), written under the '/**' key so that it
        reaches the node in this graph's namespace (a plain `node:` key names the node without a namespace and
        would be silently ignored); its path, for --params-file."""
        import yaml
        merged = {}
        for path in files:
            merged.update((yaml.safe_load(Path(path).read_text()) or {}).get(node, {}).get('ros__parameters', {}))
        out = self.log_dir / f'{node}_params.yaml'
        out.write_text(yaml.safe_dump({'/**': {'ros__parameters': merged}}))
        return str(out)

    def bridge(self, url, **params):
        args = ['-m', 'quad_bridge.mavlink_bridge_node', '--ros-args', '-p', f'fcu_url:={url}']
        for k, v in {**BRIDGE_DEFAULTS, **params}.items():
            args += ['-p', f'{k}:={v}']
        return self.start('bridge', args)

    def controller(self, *param_files, **params):
        """position_controller on the wall clock: the parameter files (paths under the repository, in order;
        through params_file), then the parameters; the vehicle file is the emulator's unless given."""
        args = ['-m', 'quad_control.position_controller_node', '--ros-args',
                '--params-file', self.params_file('position_controller', *(ROOT / p for p in param_files))]
        for k, v in {'vehicle': VEHICLE_FILE, **params}.items():
            args += ['-p', f'{k}:={v}']
        return self.start('controller', args)

    def odom_probe(self):
        """test/odom_probe.py: odometry arrivals seen from a process of their own (read back with odom_arrivals)."""
        return self.start('odom_probe', [str(ROOT / 'test' / 'odom_probe.py'), '--ros-args'])

    def odom_arrivals(self):
        """(arrival_s on CLOCK_MONOTONIC, stamp_s) arrays of what the odom probe has received so far."""
        from odom_probe import read
        return read(self.log('odom_probe'))


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


class Observer:
    """Subscribes odom, diagnostics, control/reference, trajectory; calls the bridge's services."""

    def __init__(self, domain_id, namespace):
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node('bridge_test_observer', namespace=namespace, context=self.context)
        self.lock = threading.Lock()
        self.odom, self.diagnostics, self.references, self._trajectory_raw = [], {}, [], None
        self._trajectory_pub = None
        self.tilt = []   # (stamp, tilt from level in deg) of each odom
        self.node.create_subscription(Odometry, 'odom', self._on_odom, 10)
        self.node.create_subscription(DiagnosticArray, 'diagnostics', self._on_diag, 10)
        self.node.create_subscription(MultiDOFJointTrajectory, 'control/reference', self._on_ref, 10)
        latched = rclpy.qos.QoSProfile(depth=1, durability=rclpy.qos.DurabilityPolicy.TRANSIENT_LOCAL)
        self.node.create_subscription(MultiDOFJointTrajectory, 'trajectory', self._on_traj, latched, raw=True)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.spinner = Spinner(self.executor, [self.node], name='observer')

    def _on_odom(self, msg):
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        tilt_deg = math.degrees(math.acos(max(-1.0, min(1.0, 1.0 - 2.0 * (q.x * q.x + q.y * q.y)))))  # R_33
        with self.lock:
            self.odom.append((stamp_to_s(msg.header.stamp), (p.x, p.y, p.z)))
            self.tilt.append((stamp_to_s(msg.header.stamp), tilt_deg))

    def _on_diag(self, msg):
        with self.lock:
            for st in msg.status:
                self.diagnostics.setdefault(st.name, []).append(
                    (time.monotonic(), st.message, {kv.key: kv.value for kv in st.values}))

    def _on_ref(self, msg):
        t = msg.points[0].transforms[0].translation
        with self.lock:
            self.references.append((stamp_to_s(msg.header.stamp), (t.x, t.y, t.z)))

    def _on_traj(self, raw):
        self._trajectory_raw = raw   # decoded when asked for: a 10,000-point plan costs ~1 s of Python

    def forget_trajectory(self):
        """The next `trajectory` read is None until a new plan arrives."""
        self._trajectory_raw = None

    @property
    def trajectory(self):
        """The latest `trajectory` (MultiDOFJointTrajectory), or None."""
        raw = self._trajectory_raw
        return None if raw is None else deserialize_message(raw, MultiDOFJointTrajectory)

    def link(self):
        """(message, values) of the newest `mavlink_bridge: link` status, or (None, {})."""
        return self.status('mavlink_bridge: link')

    def setpoints(self):
        """(message, values) of the newest `mavlink_bridge: setpoints` status, or (None, {})."""
        return self.status('mavlink_bridge: setpoints')

    def status(self, name):
        with self.lock:
            entries = self.diagnostics.get(name)
            return entries[-1][1:] if entries else (None, {})

    def controller(self):
        """(message, values) of the newest position_controller status, or (None, {})."""
        return self.status(contract.CONTROLLER_STATUS)

    def publish_trajectory(self, msg):
        """Publishes `trajectory` latched, as trajectory_node does."""
        if self._trajectory_pub is None:
            self._trajectory_pub = self.node.create_publisher(MultiDOFJointTrajectory, contract.TRAJECTORY,
                                                              contract.qos(contract.TRAJECTORY))
        self._trajectory_pub.publish(msg)

    def position(self):
        with self.lock:
            return self.odom[-1][1] if self.odom else None

    def wait_for(self, condition, what, timeout_s=WAIT_S):
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if condition():
                return
            time.sleep(0.05)
        raise AssertionError(f'timed out after {timeout_s} s waiting for {what}')

    def call(self, name, request, timeout_s=WAIT_S):
        srv_type = Trigger if isinstance(request, Trigger.Request) else SetBool
        client = self.node.create_client(srv_type, name)
        try:
            assert client.wait_for_service(timeout_sec=timeout_s), f'service {name} not offered'
            future = client.call_async(request)
            self.wait_for(future.done, f'{name} response', timeout_s)
            return future.result()
        finally:
            self.node.destroy_client(client)

    def close(self):
        try:
            self.spinner.close()
        finally:
            self.context.try_shutdown()


OFFBOARD_MODE = {'px4': 'OFFBOARD', 'ardupilot': 'GUIDED_NOGPS'}
# what each emulated autopilot is told at boot, as docs/bridge.md's checklist says for thrust mode: ArduPilot flies
# the thrust field as thrust with GUID_OPTIONS bit 3 (its default 0 is a climb rate; the bridge's default
# ardupilot_thrust_mode is thrust)
# the emulator stands in for a flight controller, which has a processor of its own: above our nodes (the bridge and
# the controller run at SCHED_FIFO 20), so that a busy test machine starves our code, never the vehicle's
EMULATOR_SCHEDULING = ('--realtime-priority', '30')
VEHICLE_PARAMS = {'px4': (), 'ardupilot': ('--param', 'GUID_OPTIONS=8')}


def start_vehicle_graph(procs, flavour, port, controller_files=(), position=(0.0, 0.0, 1.0), bridge_port=None,
                        bridge=None, controller=None, vehicle_extra=()):
    """The emulated vehicle (sending to udp `port`, VEHICLE_PARAMS and vehicle_extra), mavlink_bridge (listening on
    `bridge_port`, default `port`: another port puts a Tap between them; `bridge` parameters) and
    position_controller (parameter files, then `controller` parameters)."""
    procs.vehicle(flavour, f'udpout:127.0.0.1:{port}', position=position,
                  extra=(*VEHICLE_PARAMS[flavour], *vehicle_extra))
    procs.bridge(f'udpin:127.0.0.1:{bridge_port or port}', **(bridge or {}))
    procs.controller(*controller_files, **(controller or {}))


def enter_offboard(observer, flavour):
    """Once the bridge sees the armed vehicle and the controller holds: `offboard`, until the bridge reports the
    offboard mode."""
    observer.wait_for(lambda: observer.link()[1].get('armed') == 'True', 'the bridge to see the armed vehicle')
    observer.wait_for(lambda: observer.references, 'the controller to hold position')
    result = observer.call('offboard', SetBool.Request(data=True))
    assert result.success, result.message
    observer.wait_for(lambda: observer.link()[1].get('mode') == OFFBOARD_MODE[flavour],
                      f'mode {OFFBOARD_MODE[flavour]}')


def hover_in_offboard(procs, observer, flavour, port, **graph):
    """start_vehicle_graph(..., **graph), then enter_offboard: the vehicle hovering under our controller."""
    start_vehicle_graph(procs, flavour, port, **graph)
    enter_offboard(observer, flavour)


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
def running_graph(log_dir: Path):
    """(Processes, Observer) in a ROS domain of their own; every process is stopped at the end."""
    namespace = f'/bridge_test_{os.getpid()}_{next(_GRAPHS)}'
    with isolated_domain() as (domain, env):
        procs = Processes(env, log_dir, namespace)
        observer = Observer(domain, namespace)
        try:
            yield procs, observer
        finally:
            procs.stop_all()
            observer.close()


@contextmanager
def tapped_graph(tmp_path):
    """running_graph plus start(flavour, position, extra, **bridge_params): an emulated vehicle and the bridge
    joined through a Tap (the wire seen between them), once the bridge sees the vehicle armed; yields
    (procs, observer, start) and closes every tap."""
    taps = []
    with running_graph(tmp_path) as (procs, observer):
        def start(flavour, position=(0.0, 0.0, 1.0), extra=(), **bridge_params):
            bridge_port = free_udp_port()
            tap = Tap(bridge_port)
            taps.append(tap)
            procs.vehicle(flavour, f'udpout:127.0.0.1:{tap.port}', position=position, extra=extra)
            procs.bridge(f'udpin:127.0.0.1:{bridge_port}', **bridge_params)
            observer.wait_for(lambda: observer.link()[1].get('armed') == 'True', 'the bridge to see the armed vehicle')
            return tap
        try:
            yield procs, observer, start
        finally:
            for tap in taps:
                tap.close()
