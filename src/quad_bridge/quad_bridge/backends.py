"""The registry of autopilot backends: a new flavour is its own file plus one entry here."""

from quad_bridge.ardupilot import ArduPilot
from quad_bridge.backend import Backend
from quad_bridge.px4 import Px4

BACKENDS = {b.key: b for b in (Px4(), ArduPilot())}   # the `autopilot` parameter's names


def backend_for(autopilot: int) -> Backend:
    """The backend of a HEARTBEAT.autopilot (MAV_AUTOPILOT) value; ValueError naming it when there is none."""
    for b in BACKENDS.values():
        if b.autopilot == autopilot:
            return b
    names = ', '.join(f'{b.name} ({b.autopilot})' for b in BACKENDS.values())
    raise ValueError(f'autopilot {autopilot} has no backend: one of {names}')


def resolve(setting: str, heartbeat_autopilot: int) -> Backend:
    """A named flavour forces it; 'auto' takes it from HEARTBEAT.autopilot."""
    if setting in BACKENDS:
        return BACKENDS[setting]
    try:
        return backend_for(heartbeat_autopilot)
    except ValueError as exc:
        raise ValueError(f'autopilot = auto: {exc}; set autopilot to one of {", ".join(BACKENDS)}') from None
