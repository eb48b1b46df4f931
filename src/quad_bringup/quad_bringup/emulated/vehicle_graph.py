"""The real-vehicle graph run from Python on one machine: quad_vehicle_emu's emulated autopilot, mavlink_bridge and
position_controller as processes on loopback UDP (Processes, start_vehicle_graph), in a ROS domain and namespace of
their own (running_graph), watched and commanded from a node in this process (Observer: odom, diagnostics,
control/reference, trajectory; the bridge's services), taken into offboard as a pilot would (enter_offboard).
The harness of the bridge graph tests (test/) and of the bridge benches (bench/); quad_bringup.emulated.mission_flight
flies and scores a mission through it. It runs the packages of this checkout (python_env: src/ on PYTHONPATH, the
processes' working directory the checkout's root)."""

import fcntl
import itertools
import math
import os
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
from rclpy.serialization import deserialize_message
from std_srvs.srv import SetBool, Trigger
from trajectory_msgs.msg import MultiDOFJointTrajectory

from quad_bridge.parameters import NAME as BRIDGE_NAME
from quad_common import contract
from quad_common.conversions import stamp_to_s
from quad_common.paths import REPO_ROOT
from quad_common.ros.testing import Spinner, isolated_domain

ROOT = REPO_ROOT   # the checkout whose packages and config/ the processes use
VEHICLE_FILE = str(ROOT / 'config' / 'vehicles' / 'px4_quad.yaml')
WAIT_S = 90.0  # generous: a busy 2-core machine
PORT_TAKEN = 'Address already in use'   # the bridge's refusal when its udpin port is bound by another process
PORT_TRIES = 3
_GRAPHS = itertools.count()


# Ports the tests hand to a process that binds them later (a bridge's udpin, an emulator's tcpin). They lie below
# Fast DDS's (7400 + 250 * domain), below the UDP ports every DDS participant of these graphs binds from 7000 up
# (one each: 7000-7005 seen with three flights at once; in that band the bridge's udpin found its test port taken),
# and below the kernel's ephemeral range (ip_local_port_range, 32768 and up), so no socket gets one unless it names
# it: a port bound to 0 and closed again could be any process's ephemeral port before the test's process binds it.
# Test processes share them through lock files, held until the process exits.
TEST_PORTS = range(6100, 7000)
_PORT_LOCK_DIR = Path(tempfile.gettempdir()) / 'quadflight-test-ports'
_EPHEMERAL_RANGE = Path('/proc/sys/net/ipv4/ip_local_port_range')
_held_ports = []


def _check_test_ports_outside_ephemeral():
    if _EPHEMERAL_RANGE.is_file():
        low, high = map(int, _EPHEMERAL_RANGE.read_text().split())
        if low <= TEST_PORTS[-1] and TEST_PORTS[0] <= high:
            raise RuntimeError(f'ip_local_port_range {low}-{high} overlaps the test ports '
                               f'{TEST_PORTS[0]}-{TEST_PORTS[-1]} (vehicle_graph.TEST_PORTS)')


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

    def bridge(self, url, script=None, **params):
        """mavlink_bridge (or `script`, a path that runs it, for a test's instrumented bridge) on `url`."""
        entry = [script] if script else ['-m', 'quad_bridge.mavlink_bridge_node']
        args = [*entry, '--ros-args', '-p', f'fcu_url:={url}']
        for k, v in params.items():
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

    def status_count(self, name) -> int:
        """How many statuses `name` the observer has received."""
        with self.lock:
            return len(self.diagnostics.get(name, ()))

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


def start_bridge(procs, url: str, **params):
    """mavlink_bridge on `url` (`params` its parameters), once it listens there (its start-up line, written after the
    link is open); None, the bridge stopped, if another process held the port (it exits 2 saying PORT_TAKEN: one
    that claims no test port); any other exit fails naming it, with the bridge's log."""
    bridge = procs.bridge(url, **params)
    started = f'{BRIDGE_NAME}: {url},'
    deadline = time.monotonic() + WAIT_S
    while bridge.poll() is None and started not in procs.log('bridge'):
        if time.monotonic() > deadline:
            raise AssertionError(f'the bridge did not open {url} within {WAIT_S} s: {procs.log("bridge")[-2000:]}')
        time.sleep(0.05)
    if bridge.poll() is None:
        return bridge
    log = procs.log('bridge')
    procs.stop('bridge')
    if PORT_TAKEN in log:
        return None
    raise AssertionError(f'the bridge exited with {bridge.returncode}: {log[-2000:]}')


def start_vehicle_graph(procs, flavour, port, controller_files=(), position=(0.0, 0.0, 1.0), bridge_port=None,
                        bridge=None, controller=None, vehicle_extra=()):
    """The emulated vehicle (sending to udp `port`, VEHICLE_PARAMS and vehicle_extra), mavlink_bridge (listening on
    `bridge_port`, default `port`: another port puts a Tap between them; `bridge` parameters) and
    position_controller (parameter files, then `controller` parameters). Without a Tap, a port another process
    holds is given up for a new one (PORT_TRIES in all)."""
    for _ in range(1 if bridge_port else PORT_TRIES):
        procs.vehicle(flavour, f'udpout:127.0.0.1:{port}', position=position,
                      extra=(*VEHICLE_PARAMS[flavour], *vehicle_extra))
        if start_bridge(procs, f'udpin:127.0.0.1:{bridge_port or port}', **(bridge or {})) is not None:
            break
        procs.stop('vehicle')
        port = free_udp_port()
    else:
        raise AssertionError(f'the bridge found its port taken {1 if bridge_port else PORT_TRIES} times')
    procs.controller(*controller_files, **(controller or {}))


def enter_offboard(observer, flavour, bridge_counts_setpoints=True):
    """Once the bridge sees the armed vehicle, the controller holds and its setpoints reach the bridge: `offboard`,
    until the bridge reports the offboard mode. (The observer seeing the controller's reference does not mean the
    bridge has matched its setpoint publisher yet: the bridge refuses `offboard` without a live stream.) A bridge
    whose setpoints status has no `received` count (bench_bridge_arrival's baseline code) is asked again at each
    of its statuses while it refuses for want of a live stream."""
    observer.wait_for(lambda: observer.link()[1].get('armed') == 'True', 'the bridge to see the armed vehicle')
    observer.wait_for(lambda: observer.references, 'the controller to hold position')
    if bridge_counts_setpoints:
        observer.wait_for(lambda: int(observer.setpoints()[1].get('received', 0)) > 0,
                          'the bridge to receive setpoints')
    statuses = observer.status_count('mavlink_bridge: setpoints')
    result = observer.call('offboard', SetBool.Request(data=True))
    while not bridge_counts_setpoints and not result.success and 'no live setpoint stream' in result.message:
        observer.wait_for(lambda seen=statuses: observer.status_count('mavlink_bridge: setpoints') > seen,
                          "the bridge's next setpoints status")
        statuses = observer.status_count('mavlink_bridge: setpoints')
        result = observer.call('offboard', SetBool.Request(data=True))
    assert result.success, result.message
    observer.wait_for(lambda: observer.link()[1].get('mode') == OFFBOARD_MODE[flavour],
                      f'mode {OFFBOARD_MODE[flavour]}')


def hover_in_offboard(procs, observer, flavour, port, **graph):
    """start_vehicle_graph(..., **graph), then enter_offboard: the vehicle hovering under our controller."""
    start_vehicle_graph(procs, flavour, port, **graph)
    enter_offboard(observer, flavour)


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
