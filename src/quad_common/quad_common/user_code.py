"""Loading the user's own code by name: `package.module:Name` (a controller class, a trajectory class).

User code is input like any other: whatever its import raises is one refusal naming the name, the error and the
user's line, never a traceback."""

import importlib
import traceback


def user_line(exc: BaseException) -> str:
    """' (file:line)' of the innermost frame of a traceback ('' without one)."""
    frames = traceback.extract_tb(exc.__traceback__)
    return f' ({frames[-1].filename}:{frames[-1].lineno})' if frames else ''


def load_attribute(name: str, refused: str, error=ValueError):
    """The object `package.module:Attr.Sub` names; error(f'{refused}: why') when the import fails or the module
    lacks it (refused: the field and value as the user wrote them, e.g. "controller = 'x:Y' refused")."""
    module_name, _, attr = name.partition(':')
    try:
        found = importlib.import_module(module_name)
    except Exception as exc:  # noqa: BLE001  (user code: any import error is a refusal)
        raise error(f'{refused}: importing {module_name!r} failed: {type(exc).__name__}: {exc}'
                    f'{user_line(exc)}') from None
    for part in attr.split('.'):
        found = getattr(found, part, None)
        if found is None:
            raise error(f'{refused}: module {module_name!r} has no {attr!r}')
    return found
