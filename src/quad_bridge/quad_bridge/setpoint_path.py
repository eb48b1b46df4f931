"""The setpoint half of mavlink_bridge (rclpy): `cmd/attitude_thrust` through a node and a thread of its own
(services waiting for an ACK never delay a setpoint, a setpoint never waits for them), checked, and put on the
wire at once by quad_bridge.setpoint_stream when the hand-over allows it.

The thread waits on a wait set of its own (the subscription and a wake-up guard condition), bounded by the
keep-alive's next deadline, and runs the keep-alive itself (SetpointStreamer.tick): one thread and one wake-up
per setpoint where a setpoint thread, an executor's periodic pass over the node and a keep-alive thread would each
wake every period. After a stall it takes every setpoint queued, oldest first, each on the wire as
it is taken, so the newest goes out last and wins (the subscription keeps the newest SETPOINT_QUEUE_DEPTH, and
the publisher's KEEP_LAST history drops its oldest, never its newest)."""

import math
import threading

import rclpy
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy  # WaitSet, GuardCondition
from sensor_msgs.msg import Imu

from quad_bridge import frames
from quad_bridge.mavlink_client import mavlink
from quad_bridge.setpoint import setpoint_from_cdr
from quad_bridge.setpoint_source import SetpointSource, fully_qualified
from quad_bridge.setpoint_stream import SetpointStreamer
from quad_common import contract

# DDS keeps this many setpoints for us while the interpreter is busy elsewhere (its reader thread is not held by
# the GIL): a 0.1 s stall at 500 Hz loses none (bench/bench_bridge.py; depth 10 lost 3-5 % at 100-500 Hz).
SETPOINT_QUEUE_DEPTH = 100
ATTITUDE_RATES_IGNORE = (mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE
                         | mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE
                         | mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_YAW_RATE_IGNORE)


class SetpointPath:
    def __init__(self, bridge, may_stream, on_quiet):
        """bridge: the MavlinkBridge (params, vehicle, client, commander.flying_config, now_s); may_stream() -> bool;
        on_quiet(wire_age_s, input_age_s): see SetpointStreamer."""
        self.bridge, self.params, self.log = bridge, bridge.params, bridge.get_logger()
        self.counts_lock = threading.Lock()
        self.refused = self.clamped = self.clamp_short = 0
        self._wake = _rclpy.GuardCondition(bridge.context.handle)
        self.streamer = SetpointStreamer(self.send, may_stream, self.params['setpoint_rate_hz'],
                                         self.params['setpoint_timeout_s'], on_quiet, on_error=self._error,
                                         wake=self._wake.trigger_guard_condition)
        # Its own name through a node-local remap: rcl applies local remaps before the process-wide ones, so the
        # `-r __node:=NAME` that launch_ros gives the process renames the bridge, never this node too.
        name = f'{bridge.get_name()}_setpoints'
        self.node = rclpy.create_node(name, namespace=bridge.get_namespace(), context=bridge.context,
                                      cli_args=['--ros-args', '-r', f'__node:={name}'],
                                      start_parameter_services=False)
        self.sub = self.node.create_subscription(Imu, contract.SETPOINT, self.on_setpoint, SETPOINT_QUEUE_DEPTH,
                                                 raw=True)
        source = fully_qualified(self.params['setpoint_source'], bridge.get_namespace())
        self.source = SetpointSource(self.node, self.sub, source, self.log) if source else None
        self._take = self.source.take_one if self.source else self._take_any
        self.stopping = threading.Event()
        self.thread = threading.Thread(target=self._spin, name='setpoint-rx', daemon=True)

    def start(self):
        self.streamer.start()
        self.thread.start()

    def stop(self):
        self.stopping.set()
        self.streamer.stop()
        self._wake.trigger_guard_condition()
        self.thread.join(timeout=2.0)
        self.node.destroy_node()
        self._wake.destroy_when_not_in_use()
        if self.source:
            self.source.close()

    def counts(self) -> dict:
        with self.counts_lock:
            counts = {'refused': self.refused, 'clamped': self.clamped, 'clamp_vertical_not_kept': self.clamp_short}
        return {**counts, **(self.source.counts() if self.source else {'setpoint_source': '(any publisher)'})}

    def refused_sources(self) -> str:
        """Who was refused as not setpoint_source (for a service's answer), or ''."""
        return self.source.counts()['refused_publishers'] if self.source else ''

    def _take_any(self, sub):
        """(taken, serialized setpoint or None) without a source gate."""
        taken = sub.handle.take_message(sub.msg_type, True)
        return (False, None) if taken is None else (True, taken[0])

    def _spin(self):
        context, sub, streamer = self.bridge.context, self.sub, self.streamer
        try:
            wait_set = _rclpy.WaitSet(1, 1, 0, 0, 0, 0, context.handle)
        except Exception:   # a Ctrl-C that shut rclpy down before this thread began: the node is stopping
            if context.ok() and not self.stopping.is_set():
                raise
            return
        delay_s = 0.0
        while not self.stopping.is_set():
            wait_set.clear_entities()
            wait_set.add_subscription(sub.handle)
            wait_set.add_guard_condition(self._wake)
            try:
                wait_set.wait(int(delay_s * 1e9))
                if wait_set.is_ready('subscription', 0):
                    self._take_all(sub)
                elif self.source is not None:   # a publisher held until the graph names it
                    raw = self.source.release()
                    if raw is not None:
                        self.on_setpoint(raw)
            except Exception:
                if context.ok() and not self.stopping.is_set():
                    raise
                return
            delay_s = streamer.tick()

    def _take_all(self, sub):
        """Every setpoint queued, in order (on_setpoint: each on the wire as it is taken)."""
        while True:
            taken, raw = self._take(sub)
            if not taken:
                return
            if raw is not None:
                self.on_setpoint(raw)

    def on_setpoint(self, raw: bytes):
        """A serialized cmd/attitude_thrust (quad_common.ros.cdr: no Python message object on the hot path)."""
        vehicle = self.bridge.vehicle
        with vehicle.lock:
            backend = vehicle.status.backend
        f_max = backend.max_specific_force(self.bridge.commander.flying_config) if backend else math.inf
        try:
            sp, clamped, kept = setpoint_from_cdr(raw, math.radians(self.params['max_tilt_deg']), f_max)
        except ValueError as exc:
            with self.counts_lock:
                self.refused += 1
            self.log.warn(f'setpoint refused ({self.refused} so far): {exc}', throttle_duration_sec=1.0)
            return
        if clamped:
            with self.counts_lock:
                self.clamped += 1
                self.clamp_short += not kept
            self.log.warn(f'setpoint tilt clamped to {self.params["max_tilt_deg"]} deg ({self.clamped} so far)'
                          f'{"" if kept else ": vertical acceleration NOT kept, thrust at its limit"}',
                          throttle_duration_sec=1.0)
        self.streamer.submit(sp)

    def send(self, sp):
        """One SET_ATTITUDE_TARGET (NED/FRD, the backend's thrust semantics); while the geofence brakes, its
        braking setpoint for the newest state instead (quad_bridge.geofence)."""
        vehicle, geofence = self.bridge.vehicle, self.bridge.geofence
        with vehicle.lock:
            s = vehicle.status
            if geofence.braking and s.state is not None:
                sp = geofence.braking_setpoint(s.state)
            vz = s.state.velocity[2] if s.state is not None else 0.0
            system, thrust = s.system, s.backend.thrust(sp, self.bridge.commander.flying_config, vz)
        if sp.body_rates is None:
            mask, rates = ATTITUDE_RATES_IGNORE, (0.0, 0.0, 0.0)
        else:
            mask, rates = 0, tuple(map(float, frames.body_flu_frd(sp.body_rates)))
        q = frames.enu_to_mavlink_quaternion(sp.quaternion)
        self.bridge.client.send_attitude_target(int(self.bridge.now_s() * 1000) & 0xFFFFFFFF, system,
                                                self.params['target_component'], mask, q, *rates, thrust)

    def _error(self, exc):
        self.log.error(f'setpoint keep-alive: {exc!r}', throttle_duration_sec=1.0)
