"""The autopilot backend: everything that differs between autopilots, behind one interface.

A backend says how a mode is encoded, which mode `offboard` asks for and which modes obey
SET_ATTITUDE_TARGET at all, which modes land / hold, how a specific force becomes the message's thrust
field, what it requires before arming, which vehicle parameters decide those semantics (and when they
contradict the bridge's configuration), and which telemetry the autopilot really streams.
quad_bridge.px4 and quad_bridge.ardupilot implement it; quad_bridge.backends registers them. Adding an
autopilot flavour is one new file and one entry there. No rclpy here.
"""

import math
from dataclasses import dataclass, replace

import numpy as np

from quad_common import rotations
from quad_common.types import GRAVITY_MPS2, AttitudeSetpoint

MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_MODE_FLAG_SAFETY_ARMED = 128
MAV_SYS_STATUS_PREARM_CHECK = 0x10000000  # common.xml MAV_SYS_STATUS_SENSOR: "pre-arm check status"


@dataclass(frozen=True)
class BridgeConfig:
    """What the bridge is configured with (and, with vehicle_params: adopt, what it takes from the vehicle)."""

    hover_throttle: float = 0.5
    hover_throttle_tolerance: float = 0.03          # |vehicle hover thrust - hover_throttle| allowed
    ardupilot_thrust_mode: str = 'thrust'          # ArduPilot only: thrust | climb_rate (GUID_OPTIONS bit 3)
    angle_boost: bool = True               # ArduPilot only: ATC_ANGLE_BOOST (1/cos(tilt) applied by the vehicle)
    ardupilot_speed_up_mps: float = 2.5
    ardupilot_speed_down_mps: float = 1.5
    climb_rate_lead_s: float = 0.5
    setpoint_rate_hz: float = 50.0
    setpoint_timeout_s: float = 0.5
    external_pose_enabled: bool = False          # an external pose (motion capture) is forwarded to the estimator


@dataclass(frozen=True)
class StreamGroup:
    """A kind of telemetry and the message sets that carry it, in order of preference: the bridge requests
    the first set, and the next when one of its messages never arrives."""

    name: str
    options: tuple            # tuple of tuples of MAVLink message names
    share: float = 1.0        # of telemetry_rate_hz; 0: a fixed 2 Hz


@dataclass(frozen=True)
class ParamCheck:
    """Outcome of comparing the vehicle's parameters with the configuration."""

    problems: tuple = ()      # contradictions: `offboard` is refused with these
    notes: tuple = ()         # worth saying, not a refusal
    config: BridgeConfig | None = None  # the configuration to fly with (adopted values applied)


def tilt_cos(quaternion) -> float:
    """cos of the angle between body z and world z: R[2, 2] (the same in ENU/FLU and NED/FRD)."""
    return float(rotations.to_matrix(quaternion)[2, 2])


class Backend:
    """Base class; subclasses fill in the class attributes and override what differs."""

    autopilot = -1             # HEARTBEAT.autopilot (MAV_AUTOPILOT)
    key = ''                   # its name in the `autopilot` parameter
    name = '?'
    offboard_mode = ''         # the mode `offboard` asks for
    obeying_modes = frozenset()  # every mode in which the vehicle flies SET_ATTITUDE_TARGET
    land_mode = ''
    prestream = False          # must setpoints stream before the switch into offboard_mode?
    semantic_params = ()       # parameter names read on connect (PARAM_REQUEST_READ)
    external_pose_params = ()  # ... and these with an external pose: the estimator must be set up to fuse it
    telemetry = ()             # StreamGroup, ...

    # --- modes ----------------------------------------------------------------------------------
    def external_pose_messages(self, pose) -> tuple:
        """An external pose (quad_bridge.external_pose.PoseNed) as this autopilot's estimator takes it:
        ((pymavlink send name, args), ...)."""
        raise NotImplementedError

    def mode_name(self, custom_mode: int) -> str:
        raise NotImplementedError

    def mode_params(self, name: str) -> tuple[int, int]:
        """(param2, param3) of MAV_CMD_DO_SET_MODE (param1 = MAV_MODE_FLAG_CUSTOM_MODE_ENABLED)."""
        raise NotImplementedError

    def custom_mode(self, name: str) -> int:
        """HEARTBEAT.custom_mode of a mode name."""
        raise NotImplementedError

    def hold_mode(self, stale_action: str) -> str:
        """The mode a stale stream or `offboard false` commands."""
        return self.land_mode

    def obeys_setpoints(self, mode: str) -> bool:
        return mode in self.obeying_modes

    # --- arming ---------------------------------------------------------------------------------
    def arm_refusal(self, mode: str, handing_over: bool) -> str | None:
        """Why `arm` is refused in `mode` (None: allowed)."""
        return None

    def prearm_ready(self, present: int, enabled: int, health: int) -> bool | None:
        """The autopilot's pre-arm verdict from SYS_STATUS (None: it gives none)."""
        return bool(health & MAV_SYS_STATUS_PREARM_CHECK)

    # --- thrust ---------------------------------------------------------------------------------
    def thrust(self, sp: AttitudeSetpoint, config: BridgeConfig, vertical_velocity_mps: float = 0.0) -> float:
        """The SET_ATTITUDE_TARGET thrust field for a setpoint (ENU quaternion, specific force)."""
        raise NotImplementedError

    def specific_force(self, thrust: float, config: BridgeConfig, quaternion) -> float:
        """What the vehicle makes of a thrust field (thrust semantics only): the inverse of thrust()."""
        raise NotImplementedError

    def max_specific_force(self, config: BridgeConfig) -> float:
        """The specific force of a full thrust field (1) at level attitude."""
        return GRAVITY_MPS2 / config.hover_throttle

    # --- parameters -----------------------------------------------------------------------------
    def decode_param(self, value: float, param_type: int) -> float:
        return float(value)

    def check_params(self, values: dict, config: BridgeConfig, policy: str) -> ParamCheck:
        """Compare the vehicle's semantic parameters with `config`. policy: check (contradictions refuse
        offboard) | adopt (take the vehicle's values) | ignore (trust the configuration, say so)."""
        missing = [n for n in self.param_names(config) if n not in values]
        if policy == 'ignore':
            return ParamCheck(notes=('vehicle_params = ignore: the vehicle\'s parameters are not checked',),
                              config=config)
        if missing:
            return ParamCheck(problems=(f'parameter(s) {", ".join(missing)} not read from the vehicle '
                                        '(no PARAM_VALUE); set vehicle_params: ignore to fly on the configuration',),
                              config=config)
        check = self._check(values, config, policy == 'adopt')
        if not config.external_pose_enabled:
            return check
        problems, notes = self._check_external_pose(values)
        return replace(check, problems=check.problems + problems, notes=check.notes + notes)

    def param_names(self, config: BridgeConfig) -> tuple:
        """The vehicle parameters read on connect for this configuration."""
        return self.semantic_params + (self.external_pose_params if config.external_pose_enabled else ())

    def _check(self, values, config, adopt) -> ParamCheck:
        return ParamCheck(config=config)

    def _check_external_pose(self, values) -> tuple[tuple, tuple]:
        """(problems, notes) of the estimator's set-up for an external pose; never adopted: the vehicle must be
        configured (a parameter change reboots the estimator)."""
        return (), ()

    def _hover(self, param: str, values, config, adopt, problems, notes):
        """The hover thrust rule shared by both autopilots: |vehicle - hover_throttle| <= hover_tolerance."""
        vehicle = values[param]
        if adopt:
            notes.append(f'hover_throttle {config.hover_throttle:.3f} -> {param} {vehicle:.3f} (adopted)')
            return replace(config, hover_throttle=float(np.clip(vehicle, 0.05, 0.95)))
        if abs(vehicle - config.hover_throttle) > config.hover_throttle_tolerance:
            problems.append(f'{param} = {vehicle:.3f} on the vehicle but hover_throttle = {config.hover_throttle:.3f} '
                            f'(tolerance {config.hover_throttle_tolerance}): set hover_throttle to {vehicle:.3f}')
        return config


def rate_interval_us(rate_hz: float) -> float:
    return 1e6 / rate_hz if rate_hz > 0 and math.isfinite(rate_hz) else 5e5
