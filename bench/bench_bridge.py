"""mavlink_bridge: latency from publishing cmd/attitude_thrust to its SET_ATTITUDE_TARGET datagram arriving at a
UDP listener on loopback (p50/p99), and the highest setpoint_rate_hz the bridge sustains without loss."""

import os
import socket
import struct
import subprocess
import sys
import threading
import time

import numpy as np
import rclpy
from sensor_msgs.msg import Imu

os.environ['MAVLINK20'] = '1'
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

from quad_common.testing import isolated_domain  # noqa: E402

HOVER_THROTTLE = 0.5
RUN_S = 4.0
WARM_UP_S = 1.0  # streaming before the measured window: the bridge's start-up work is not its steady state
SO_TIMESTAMPNS = getattr(socket, 'SO_TIMESTAMPNS', 35)  # Linux
NAMESPACE = f'/bench_bridge_{os.getpid()}'  # no cross-talk even with a stray graph in the same domain


def _kernel_arrival_s(ancillary) -> float:
    for level, kind, data in ancillary:
        if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS:
            sec, nsec = struct.unpack('qq', data[:16])
            return sec + nsec * 1e-9
    return time.time()


class Listener:
    """Plays the vehicle: PX4 heartbeats to the bridge, records every SET_ATTITUDE_TARGET (arrival, thrust)."""

    def __init__(self):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(('127.0.0.1', 0))
        # arrival = the kernel's receive time (CLOCK_REALTIME), not when this thread got the GIL back
        self.sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        self.sock.settimeout(0.1)
        self.port = self.sock.getsockname()[1]
        self.mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.arrivals = []
        self.bridge_addr = None
        self.running = True
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        parser = mavlink.MAVLink(None)
        parser.robust_parsing = True
        last_hb = 0.0
        hb = mavlink.MAVLink_heartbeat_message(2, 12, 129, 6 << 16, 4, 3).pack(self.mav)  # armed, OFFBOARD
        while self.running:
            if self.bridge_addr and time.monotonic() - last_hb > 0.5:
                self.sock.sendto(hb, self.bridge_addr)
                last_hb = time.monotonic()
            try:
                data, ancillary, _, addr = self.sock.recvmsg(4096, socket.CMSG_SPACE(16))
            except TimeoutError:
                continue
            self.bridge_addr = addr
            arrival_s = _kernel_arrival_s(ancillary)
            for msg in parser.parse_buffer(data) or []:
                if msg.get_type() == 'SET_ATTITUDE_TARGET':
                    self.arrivals.append((arrival_s, msg.thrust))

    def close(self):
        self.running = False
        self.thread.join(timeout=2)
        self.sock.close()


def run(rate_hz, publish_hz, env, domain, python_path):
    listener = Listener()
    bridge = subprocess.Popen([sys.executable, '-m', 'quad_bridge.mavlink_bridge_node', '--ros-args',
                               '-p', f'fcu_url:=udpout:127.0.0.1:{listener.port}', '-p', f'setpoint_rate_hz:={rate_hz}',
                               '-p', f'hover_throttle:={HOVER_THROTTLE}', '-p', 'autopilot:=px4',
                               '-r', f'__ns:={NAMESPACE}'],
                              env=dict(env, PYTHONPATH=python_path), stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain)
    node = rclpy.create_node('bench_bridge', namespace=NAMESPACE, context=context)
    pub = node.create_publisher(Imu, 'cmd/attitude_thrust', 10)
    published = {}
    try:
        deadline = time.monotonic() + 60.0
        k = 0
        streaming_since = None
        while time.monotonic() < deadline:  # until the bridge has streamed for WARM_UP_S
            k += 1
            pub.publish(_setpoint(k))
            time.sleep(0.02)
            if listener.arrivals and streaming_since is None:
                streaming_since = time.monotonic()
            if streaming_since is not None and time.monotonic() - streaming_since >= WARM_UP_S:
                break
        start = time.time()
        period = 1.0 / publish_hz
        while time.time() - start < RUN_S:
            k += 1
            published[k] = time.time()
            pub.publish(_setpoint(k))
            time.sleep(max(0.0, start + (len(published) * period) - time.time()))
        time.sleep(0.1)
        arrivals = [(t, th) for t, th in listener.arrivals if start <= t <= start + RUN_S]
    finally:
        node.destroy_node()
        context.try_shutdown()
        bridge.terminate()
        bridge.wait(timeout=20)
        listener.close()
    first = {}
    for t, thrust in arrivals:
        first.setdefault(_decode(thrust), t)
    latencies = [first[k] - t for k, t in published.items() if k in first and first[k] >= t]
    return len(arrivals) / RUN_S, np.array(latencies) * 1e3


def _setpoint(k):
    msg = Imu()
    msg.orientation.w = 1.0
    msg.linear_acceleration.z = 5.0 + (k % 1000) * 0.01
    msg.angular_velocity_covariance[0] = -1.0
    return msg


def _decode(thrust):
    return int(round((thrust * 9.81 / HOVER_THROTTLE - 5.0) / 0.01))


def main():
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    python_path = os.pathsep.join(os.path.join(root, 'src', p) for p in sorted(os.listdir(os.path.join(root, 'src'))))
    rows_latency, rows_rate = [], []
    with isolated_domain() as (domain, env):
        for rate_hz, publish_hz in ((50.0, 50.0), (200.0, 100.0)):
            sent_hz, lat = run(rate_hz, publish_hz, env, domain, python_path)
            rows_latency.append(f'| {rate_hz:.0f} | {publish_hz:.0f} | {len(lat)} | {np.percentile(lat, 50):.1f} | '
                                f'{np.percentile(lat, 99):.1f} |')
        best = 0.0
        for rate_hz in (50.0, 100.0, 200.0, 400.0, 800.0):
            sent_hz, _ = run(rate_hz, 50.0, env, domain, python_path)
            ok = sent_hz >= 0.95 * rate_hz
            rows_rate.append(f'| {rate_hz:.0f} | {sent_hz:.1f} | {"yes" if ok else "no"} |')
            if not ok:
                break
            best = rate_hz
    print('### MAVLink bridge\n')
    print('Latency from publishing `cmd/attitude_thrust` to the SET_ATTITUDE_TARGET datagram that carries it '
          'arriving at a UDP listener on loopback (the bridge re-sends the newest setpoint at '
          '`setpoint_rate_hz`, so latency includes up to one stream period), and the stream rate the bridge '
          f'sustains (>= 95 % of the set rate over {RUN_S:.0f} s). {os.cpu_count()} cores.\n')
    print('| setpoint_rate_hz | published Hz | setpoints | p50 ms | p99 ms |\n|---|---|---|---|---|')
    print('\n'.join(rows_latency))
    print('\n| setpoint_rate_hz | received Hz | sustained |\n|---|---|---|')
    print('\n'.join(rows_rate))
    print(f'\nHighest sustained setpoint rate (every lower rate sustained too): {best:.0f} Hz.')


if __name__ == '__main__':
    main()
