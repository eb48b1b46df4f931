"""The MAVLink commands the bridge sends its vehicle, and what it reads back (no rclpy): DO_SET_MODE, arm /
disarm, the telemetry it asks for on connect (MAV_CMD_SET_MESSAGE_INTERVAL) and the vehicle's semantic parameters
(PARAM_REQUEST_READ), whose check decides whether offboard may run. Blocking calls wait for the receive thread's
COMMAND_ACK / PARAM_VALUE: call them from a worker or a service, never from the receive thread."""

import threading

from quad_bridge.backend import MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, rate_interval_us
from quad_bridge.mavlink_client import mavlink, result_name

FALLBACK_RATE_HZ = 2.0   # a telemetry group without a share of telemetry_rate_hz (battery, status) is asked this rate
REQUEST_TIMEOUT_S = 1.0  # MAV_CMD_SET_MESSAGE_INTERVAL's ACK


class VehicleCommander:
    def __init__(self, client, vehicle, params, config, log, now_s):
        """client: a MavlinkClient (command_long, read_params); vehicle: quad_bridge.vehicle_state.Vehicle; params:
        the bridge's parameter values by name; config: the BridgeConfig from them; log: a logger (info / warn /
        error); now_s() -> the bridge's monotonic time (s)."""
        self.client, self.vehicle, self.params, self.config, self.log, self.now_s = (client, vehicle, params, config,
                                                                                   log, now_s)
        self.flying_config = config   # after the vehicle's parameters were checked / adopted
        self.param_check = None       # the last check (backend.ParamCheck), None before the first read
        self.param_read_lock = threading.Lock()

    def set_mode(self, name, wait=True):
        """DO_SET_MODE `name`; the bridge takes the vehicle to be in it from now until a heartbeat shows it (or the
        vehicle refuses it): quad_bridge.vehicle_state.Vehicle.mode_now. wait: return the ACK's result (None: none
        within command_timeout_s)."""
        s = self.vehicle.status
        main, sub = s.backend.mode_params(name)
        with self.vehicle.lock:
            self.vehicle.command_sent(name, self.now_s())
        result = self.client.command_long(s.system, self.params['target_component'], mavlink.MAV_CMD_DO_SET_MODE,
                                          [MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub],
                                          self.params['command_timeout_s'] if wait else None)
        if wait:
            with self.vehicle.lock:
                self.vehicle.command_answered(name, result == mavlink.MAV_RESULT_ACCEPTED)
        return result

    def arm(self, arm: bool):
        """MAV_CMD_COMPONENT_ARM_DISARM (1 arm, 0 disarm); the ACK's result (None: none within command_timeout_s)."""
        return self.client.command_long(self.vehicle.status.system, self.params['target_component'],
                                        mavlink.MAV_CMD_COMPONENT_ARM_DISARM, [1.0 if arm else 0.0],
                                        self.params['command_timeout_s'])

    def group_rate_hz(self, group):
        """A telemetry group's rate: its share of telemetry_rate_hz, or FALLBACK_RATE_HZ without one."""
        share = {g.name: g.share for g in self.vehicle.status.backend.telemetry}[group]
        return self.params['telemetry_rate_hz'] * share if share else FALLBACK_RATE_HZ

    def request_messages(self, messages, rate_hz):
        """MAV_CMD_SET_MESSAGE_INTERVAL for each message (autopilots stream nothing they were not asked for); a
        refusal is a warning (an unanswered request is not: the stream fall-back notices a missing stream)."""
        s = self.vehicle.status
        for name in messages:
            msg_id = getattr(mavlink, f'MAVLINK_MSG_ID_{name}')
            result = self.client.command_long(s.system, self.params['target_component'],
                                              mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                                              [msg_id, rate_interval_us(rate_hz)], REQUEST_TIMEOUT_S)
            if result not in (mavlink.MAV_RESULT_ACCEPTED, None):
                self.log.warn(f'{name} at {rate_hz:.0f} Hz: {result_name(result)}')

    def connect(self, streams):
        """The link came up: every telemetry group's first message set requested (streams: its
        quad_bridge.telemetry_streams.StreamSelector, started again), then the vehicle's parameters read."""
        s = self.vehicle.status
        with self.vehicle.lock:
            streams.reset(self.now_s())
        for group in s.backend.telemetry:
            self.request_messages(streams.current(group.name), self.group_rate_hz(group.name))
        self.read_vehicle_params()

    def read_vehicle_params(self):
        """PARAM_REQUEST_READ of the backend's semantic parameters; the check decides whether offboard may run.
        One read at a time (on connect and from `offboard` may overlap; their PARAM_VALUE waiters would collide)."""
        with self.param_read_lock:
            return self._read_vehicle_params()

    def _read_vehicle_params(self):
        s = self.vehicle.status
        values = {}
        if self.params['vehicle_params'] != 'ignore':
            answers = self.client.read_params(s.system, self.params['target_component'],
                                              s.backend.param_names(self.config), self.params['command_timeout_s'])
            values = {n: s.backend.decode_param(v, t) for n, (v, t) in answers.items()}
        check = s.backend.check_params(values, self.config, self.params['vehicle_params'])
        with self.vehicle.lock:
            s.params = values
            self.param_check = check
            self.flying_config = check.config
        for line in check.problems:
            self.log.error(f'offboard will be refused: {line}')
        for line in check.notes:
            self.log.warn(line)
        return check

    def current_check(self):
        """The parameter check offboard decides on: the vehicle's values now (read again: MPC_THR_HOVER may have
        been set on the vehicle since connect), or connect's check when vehicle_params is ignore."""
        check = self.param_check
        if check is None or self.params['vehicle_params'] != 'ignore':
            check = self.read_vehicle_params()
        return check
