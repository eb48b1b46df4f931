"""The geofence box (map, ENU), acted on before the edge: braking starts where the vehicle's stopping distance
would reach the box's wall, so that it stops inside.

Stopping point (a straight-line stop along the velocity v, at the braking deceleration a after the reaction
time t_r, the braking setpoint below reaching the vehicle and its attitude loop tilting it):

    p_stop = p + v_hat (|v| t_r + |v|^2 / (2 a)),   a = min(a_h / |v_hat_h|, a_v / |v_hat_z|)
    a_h = g tan(max_tilt)   (the largest horizontal deceleration that keeps the altitude; max_tilt_deg)
    a_v = VERTICAL_BRAKE_MPS2 (half of g: thrust authority kept either way)

update() each odometry state:
- BRAKE when an armed vehicle flying our setpoints has p_stop outside the box: the bridge replaces every setpoint
  it sends by brake_setpoint() (the deceleration a opposite v, the current yaw, thrust for it) until the speed is
  below STOPPED_MPS;
- BREACH (once until reset) when the vehicle has stopped while braking, or is outside the box, or, not flying
  our setpoints (nothing for the bridge to brake with), its p_stop is outside: the hand-over ends and the breach
  action (land) is commanded where the vehicle now is, inside the box.
"""

import math

import numpy as np

from quad_common import rotations
from quad_common.types import GRAVITY_MPS2, AttitudeSetpoint

VERTICAL_BRAKE_MPS2 = 0.5 * GRAVITY_MPS2
STOPPED_MPS = 0.3     # braking done: the breach action from here (an autopilot's hold/land stops the rest in cm)
BRAKE, BREACH = 'brake', 'breach'


def braking_decel_mps2(velocity, max_tilt_rad: float) -> float:
    """The deceleration a of a straight-line stop along velocity within the horizontal and vertical limits."""
    v = np.asarray(velocity, dtype=float)
    speed = float(np.linalg.norm(v))
    if speed == 0.0:
        return math.inf
    h, z = math.hypot(v[0], v[1]) / speed, abs(v[2]) / speed
    a_h = GRAVITY_MPS2 * math.tan(max_tilt_rad)
    return min(a_h / h if h > 0 else math.inf, VERTICAL_BRAKE_MPS2 / z if z > 0 else math.inf)


def stopping_point(position, velocity, max_tilt_rad: float, reaction_s: float) -> np.ndarray:
    """p_stop: where the vehicle comes to rest braking at braking_decel_mps2 after reaction_s."""
    p, v = np.asarray(position, dtype=float), np.asarray(velocity, dtype=float)
    speed = float(np.linalg.norm(v))
    if speed == 0.0:
        return p.copy()
    distance = speed * reaction_s + speed ** 2 / (2.0 * braking_decel_mps2(v, max_tilt_rad))
    return p + v / speed * distance


def brake_setpoint(velocity, yaw_rad: float, max_tilt_rad: float) -> AttitudeSetpoint:
    """The setpoint that decelerates at braking_decel_mps2 against velocity (ENU), level yaw kept: specific force
    f = g e3 - a v_hat, the body z axis along f, thrust |f|. The tilt is max_tilt exactly in a horizontal stop."""
    v = np.asarray(velocity, dtype=float)
    speed = float(np.linalg.norm(v))
    accel = -v / speed * braking_decel_mps2(v, max_tilt_rad) if speed > 0 else np.zeros(3)
    force = accel + np.array([0.0, 0.0, GRAVITY_MPS2])
    return AttitudeSetpoint(quaternion=rotations.from_body_z_and_yaw(force / np.linalg.norm(force), yaw_rad),
                            specific_force_mps2=float(np.linalg.norm(force)))


class Geofence:
    def __init__(self, enabled: bool, min_m, max_m, max_tilt_rad: float = math.radians(35.0),
                 reaction_s: float = 0.3):
        self.enabled = enabled
        self.min_m, self.max_m = np.asarray(min_m, float), np.asarray(max_m, float)
        self.max_tilt_rad, self.reaction_s = max_tilt_rad, reaction_s
        self.breached = False
        self.braking = False
        self.braked_from = None       # position, velocity where braking began
        self.breach_reason = ''

    def inside(self, point) -> bool:
        return bool(np.all(point >= self.min_m) and np.all(point <= self.max_m))

    def update(self, position, velocity, armed: bool, streaming: bool, max_tilt_rad: float | None = None) -> str | None:
        """BRAKE (once, when braking starts), BREACH (once until reset) or None; see the module. streaming: the
        vehicle flies our setpoints now; max_tilt_rad: the braking tilt now (a runtime parameter)."""
        if not self.enabled or self.breached or not armed:
            return None
        if max_tilt_rad is not None:
            self.max_tilt_rad = max_tilt_rad
        if not self.inside(position):
            return self._breach('left the box')
        if self.braking:
            if float(np.linalg.norm(velocity)) < STOPPED_MPS:
                return self._breach('stopped before the wall')
            return None if streaming else self._breach('braking ended (not flying our setpoints)')
        if self.inside(stopping_point(position, velocity, self.max_tilt_rad, self.reaction_s)):
            return None
        if not streaming:
            return self._breach('its stopping point is outside the box')
        self.braking, self.braked_from = True, (np.array(position, float), np.array(velocity, float))
        return BRAKE

    def braking_setpoint(self, state) -> AttitudeSetpoint:
        """brake_setpoint for an odometry state (its velocity and yaw)."""
        return brake_setpoint(state.velocity, float(rotations.to_euler(state.quaternion)[2]), self.max_tilt_rad)

    def _breach(self, why: str) -> str:
        self.breached, self.braking, self.breach_reason = True, False, why
        return BREACH

    def reset(self):
        """`offboard` re-enables it."""
        self.breached = self.braking = False
        self.braked_from = None
