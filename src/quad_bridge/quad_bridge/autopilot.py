"""Module-level view of the two backends for quad_sim.mavlink_vehicle, which predates them; the bridge itself
uses quad_bridge.backend. Remove once the vehicle emulator stops importing quad_bridge."""

# ruff: noqa: F401
from quad_bridge.ardupilot import (
    ANGLE_BOOST_COS_MIN,
    GUID_OPTIONS_THRUST_BIT,
    MAV_AUTOPILOT_ARDUPILOTMEGA,
    thrust_to_climb_rate,
)
from quad_bridge.backend import (
    MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
    MAV_MODE_FLAG_SAFETY_ARMED,
    ThrustConfig,
    backend_for,
    tilt_cos,
)
from quad_bridge.px4 import MAV_AUTOPILOT_PX4
from quad_bridge.px4 import custom_mode as px4_custom_mode


def mode_name(autopilot: int, custom_mode: int) -> str:
    return backend_for(autopilot).mode_name(custom_mode)


def mode_from_name(autopilot: int, name: str) -> tuple[int, int]:
    return backend_for(autopilot).mode_params(name)


def custom_mode_of(autopilot: int, param2: float, param3: float) -> int:
    b = backend_for(autopilot)
    return b.custom_mode(b.mode_name(_word(autopilot, param2, param3)))


def _word(autopilot, param2, param3):
    from quad_bridge import px4
    return px4.custom_mode(int(param2), int(param3)) if autopilot == MAV_AUTOPILOT_PX4 else int(param2)


def offboard_mode(autopilot: int) -> str:
    return backend_for(autopilot).offboard_mode


def land_mode(autopilot: int) -> str:
    return backend_for(autopilot).land_mode


def hold_mode(autopilot: int) -> str:
    return backend_for(autopilot).hold_mode('hold')


def specific_force_from_thrust(autopilot: int, thrust: float, hover_throttle: float, quaternion=None) -> float:
    return backend_for(autopilot).specific_force(thrust, ThrustConfig(hover_throttle=hover_throttle), quaternion)
