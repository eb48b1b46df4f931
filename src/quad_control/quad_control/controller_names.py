"""What a controller name means, pure Python (no numpy): ours (`pd`, `pid`, `se3`, quad_control.position), a user
class `package.module:Class`, or the name of an entry point of the group `quadflight.controllers` (an installed
package registering its classes; read with importlib.metadata). fly, sweep, tune and position_controller's
`controller` parameter refuse a name here, before a controller module (or numpy) is imported."""

import importlib.metadata
import inspect

from quad_common.params import Param
from quad_common.user_code import load_attribute

CONTROLLERS = ('pd', 'pid', 'se3')
ENTRY_POINT_GROUP = 'quadflight.controllers'


class ControllerRefused(ValueError):
    """A controller name that does not resolve, or a class that cannot be built (before anything starts)."""


def _entry_points() -> dict:
    return {ep.name: ep for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)}


def resolve(name: str):
    """The class a plugin name means (`module:Class` or an entry point's name); ControllerRefused naming why."""
    if not isinstance(name, str) or not name:
        raise ControllerRefused(f'controller = {name!r} refused: a name is needed')
    if ':' in name:
        cls = load_attribute(name, f'controller = {name!r} refused', ControllerRefused)
    else:
        points = _entry_points()
        if name not in points:
            known = ', '.join([*CONTROLLERS, *sorted(points)])
            raise ControllerRefused(f'controller = {name!r} refused: must be one of {known}, or module:Class')
        try:
            cls = points[name].load()
        except Exception as exc:  # noqa: BLE001
            raise ControllerRefused(f'controller = {name!r} refused: its entry point {points[name].value!r} '
                                    f'failed to load: {type(exc).__name__}: {exc}') from None
    if not inspect.isclass(cls) or not callable(getattr(cls, 'update', None)):
        raise ControllerRefused(f'controller = {name!r} refused: {cls!r} is not a class with an update method')
    return cls


def refusal(name) -> str | None:
    """Why `name` is not a controller (None: it is one): the parameter check of position_controller's
    `controller` (quad_common.params.Param.check), so fly, sweep, tune and the node refuse alike."""
    if name in CONTROLLERS:
        return None
    try:
        resolve(name)
    except ControllerRefused as exc:
        return str(exc)
    return None


# position_controller's `controller` parameter (quad_control.parameters.SPECS): its rule is refusal() above
CONTROLLER_PARAM = Param('controller', 'pd', 'position controller: pd (the seed eq. 1-5), pid (plus integral), se3 '
                         '(geometric), or a user class: package.module:Class or a quadflight.controllers entry point '
                         '(docs/plugins.md)', check=refusal)
