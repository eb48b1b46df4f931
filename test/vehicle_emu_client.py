"""A plain pymavlink ground station for the emulator's tests: no quad_bridge code, so the emulator's protocol is
checked against pymavlink's reading of MAVLink and the numbers the autopilots' source gives."""

import math
import os
import subprocess
import sys
import threading
import time

os.environ['MAVLINK20'] = '1'
from pymavlink import mavutil  # noqa: E402

from quad_bringup.emulated.vehicle_graph import EMULATOR_SCHEDULING, ROOT, VEHICLE_FILE, free_udp_port, python_env  # noqa: E402

WAIT_S = 60.0
PX4_MODES = {'OFFBOARD': 6 << 16, 'POSCTL': 3 << 16, 'AUTO.LOITER': 4 << 16 | 3 << 24, 'AUTO.LAND': 4 << 16 | 6 << 24}


def level_q_wxyz(roll_rad=0.0, pitch_rad=0.0, yaw_rad=0.0):
    """MAVLink [w, x, y, z] of NED/FRD Euler angles (ZYX)."""
    cr, sr = math.cos(roll_rad / 2), math.sin(roll_rad / 2)
    cp, sp = math.cos(pitch_rad / 2), math.sin(pitch_rad / 2)
    cy, sy = math.cos(yaw_rad / 2), math.sin(yaw_rad / 2)
    return [cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy]


class EmulatedVehicle:
    """The emulator process and a pymavlink GCS connected to it; every message received is kept with its
    arrival time (monotonic)."""

    def __init__(self, log_dir, flavour, *extra, tcp=False, position=(0.0, 0.0, 1.0)):
        port = free_udp_port()
        url = f'tcpin:127.0.0.1:{port}' if tcp else f'udpout:127.0.0.1:{port}'
        self.log_path = log_dir / f'vehicle_{flavour}.log'
        self.lock = threading.Lock()
        self.send_lock = threading.Lock()
        self.messages = []
        self.running = True
        self.conn = self.reader = self.stream_thread = None
        self.stream_stop = threading.Event()
        if not tcp:   # listening before the emulator sends
            self.conn = mavutil.mavlink_connection(f'udpin:127.0.0.1:{port}', source_system=255,
                                                   source_component=190)
        self.proc = subprocess.Popen(
            [sys.executable, '-m', 'quad_vehicle_emu.mavlink_vehicle', '--autopilot', flavour, '--url', url,
             '--vehicle', VEHICLE_FILE, '--initial-position', ','.join(map(str, position)),
             *EMULATOR_SCHEDULING, *extra],
            env=python_env(dict(os.environ)), stdout=open(self.log_path, 'w'), stderr=subprocess.STDOUT,
            cwd=str(ROOT))
        try:   # a vehicle that never speaks is ended here: the test's fixture only closes what it was given
            if tcp:
                self.conn = self._connect_tcp(port)
            self.reader = threading.Thread(target=self._read, daemon=True)
            self.reader.start()
            self.wait_for(lambda: self.last('HEARTBEAT'), 'the first HEARTBEAT', 90.0)
        except BaseException:
            self.close()
            raise

    def _connect_tcp(self, port):
        deadline = time.monotonic() + 90.0
        while True:
            try:
                return mavutil.mavlink_connection(f'tcp:127.0.0.1:{port}', source_system=255, source_component=190,
                                                  autoreconnect=True)
            except OSError:
                if time.monotonic() > deadline or self.proc.poll() is not None:
                    raise
                time.sleep(0.2)

    def _read(self):
        while self.running:
            try:
                msg = self.conn.recv_match(blocking=True, timeout=0.1)
            except (OSError, ValueError):
                continue
            if msg is not None and msg.get_type() != 'BAD_DATA':
                with self.lock:
                    self.messages.append((time.monotonic(), msg))

    def close(self):
        self.stop_stream()
        self.running = False
        if self.reader is not None:
            self.reader.join(timeout=2)
        self.proc.terminate()
        try:
            self.proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        if self.conn is not None:
            self.conn.close()

    # --- reading --------------------------------------------------------------------------------------

    def of_type(self, kind, since=0.0):
        with self.lock:
            return [(t, m) for t, m in self.messages if t >= since and m.get_type() == kind]

    def last(self, kind):
        found = self.of_type(kind)
        return found[-1][1] if found else None

    def wait_for(self, condition, what, timeout_s=WAIT_S):
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            result = condition()
            if result:
                return result
            if self.proc.poll() is not None:
                raise AssertionError(f'emulator exited ({self.proc.returncode}) waiting for {what}: '
                                     f'{self.log_path.read_text()[-2000:]}')
            time.sleep(0.02)
        raise AssertionError(f'timed out after {timeout_s} s waiting for {what}')

    def wait_message(self, kind, since, condition=lambda m: True, timeout_s=WAIT_S):
        def found():
            for _, m in self.of_type(kind, since):
                if condition(m):
                    return m
            return None
        return self.wait_for(found, f'{kind} after {since:.2f}', timeout_s)

    def mode(self):
        return self.last('HEARTBEAT').custom_mode

    def armed(self):
        return bool(self.last('HEARTBEAT').base_mode & 128)

    # --- commanding -----------------------------------------------------------------------------------

    def send(self, name, *args):
        with self.send_lock:
            getattr(self.conn.mav, name + '_send')(*args)

    def command(self, command, *params):
        since = time.monotonic()
        params = list(params) + [0.0] * (7 - len(params))
        self.send('command_long', 1, 1, command, 0, *params)
        return self.wait_message('COMMAND_ACK', since, lambda m: m.command == command).result

    def set_interval(self, msg_id, rate_hz):
        return self.command(511, msg_id, 1e6 / rate_hz)

    def set_mode(self, main, sub=0):
        return self.command(176, 1, main, sub)

    def param(self, name, value=None, param_type=9):
        since = time.monotonic()
        if value is None:
            self.send('param_request_read', 1, 1, name.encode(), -1)
        else:
            self.send('param_set', 1, 1, name.encode(), value, param_type)
        return self.wait_message('PARAM_VALUE', since, lambda m: m.param_id == name, 10.0)

    def start_stream(self, rate_hz, q_wxyz, thrust, type_mask=7):
        """SET_ATTITUDE_TARGET at rate_hz from a thread (until stop_stream)."""
        self.stop_stream()
        self.stream_stop.clear()
        self.stream_last_s = None

        def run():
            period = 1.0 / rate_hz
            next_s = time.monotonic()
            while not self.stream_stop.is_set():
                self.send('set_attitude_target', 0, 1, 1, type_mask, q_wxyz, 0.0, 0.0, 0.0, thrust)
                self.stream_last_s = time.monotonic()
                next_s += period
                self.stream_stop.wait(max(next_s - time.monotonic(), 0.0))
        self.stream_thread = threading.Thread(target=run, daemon=True)
        self.stream_thread.start()

    def stop_stream(self):
        """Ends the stream; the time of its last setpoint (the thread has ended: none follows)."""
        if self.stream_thread is not None:
            self.stream_stop.set()
            self.stream_thread.join(timeout=60)   # a starved thread (FIFO emulators beside it) may wake late
            assert not self.stream_thread.is_alive(), 'the setpoint stream did not stop'
            self.stream_thread = None
        return getattr(self, 'stream_last_s', None)
