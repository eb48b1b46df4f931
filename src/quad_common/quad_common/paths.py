"""Where a file named by a parameter or a command's argument is found, one rule for every node and command: the
path as given (absolute, or relative to the working directory), else in each config directory (the installed
share/quad_bringup/config, found through the ament index, then the checkout's config/), with or without a leading
`config/` (`vehicles/px4_quad.yaml` and `config/vehicles/px4_quad.yaml` name the same file)."""

import os
import tempfile
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[3]  # src/quad_common/quad_common/paths.py (symlink-install too)
SHARE_PACKAGE = 'quad_bringup'                   # the package whose share directory holds config/


def cache_dir() -> Path:
    """The project's cache folder, made if missing: $XDG_CACHE_HOME/quadflight (default ~/.cache/quadflight), or the
    temporary folder's quadflight where that cannot be made. OSError where neither can."""
    base = Path(os.environ.get('XDG_CACHE_HOME') or Path.home() / '.cache') / 'quadflight'
    try:
        base.mkdir(parents=True, exist_ok=True)
    except OSError:  # no writable home
        base = Path(tempfile.gettempdir()) / 'quadflight'
        base.mkdir(parents=True, exist_ok=True)
    return base


def share_dir() -> Path | None:
    """share/quad_bringup of the installed workspace (the ament index on AMENT_PREFIX_PATH), or None."""
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
    except ImportError:
        return None
    try:
        return Path(get_package_share_directory(SHARE_PACKAGE))
    except (PackageNotFoundError, ValueError, LookupError, OSError):  # OSError: AMENT_PREFIX_PATH unset
        return None


def config_roots() -> list[Path]:
    """The directories holding config/, in the order they are looked in."""
    roots = [d for d in (share_dir(),) if d is not None and (d / 'config').is_dir()]
    if (REPO_ROOT / 'config').is_dir():
        roots.append(REPO_ROOT)
    return roots


def candidates(path) -> list[Path]:
    """Where `path` is looked for, in order."""
    p = Path(os.fspath(path)).expanduser()
    if p.is_absolute():
        return [p]
    inside = Path(*p.parts[1:]) if p.parts[0] == 'config' and len(p.parts) > 1 else p
    return [Path.cwd() / p, *(root / 'config' / inside for root in config_roots())]


def resolve_config(path) -> Path:
    """The absolute path of the first of candidates(path) that exists.

    Raises FileNotFoundError naming the path and every place looked in when none has it.
    """
    if not os.fspath(path):
        raise FileNotFoundError("'': no file named")
    places = candidates(path)
    for place in places:
        if place.exists():
            return place
    raise FileNotFoundError(f'{path}: no such file (looked in {", ".join(map(str, places))})')


def parameter_file(name: str, value) -> str:
    """A node's file parameter `name` = value found by resolve_config (its absolute path); a ValueError naming the
    parameter, the value and every place looked in when none has it."""
    try:
        return str(resolve_config(value))
    except FileNotFoundError as exc:
        raise ValueError(f'{name} = {os.fspath(value)!r}: {exc}') from None


def input_path(value) -> Path:
    """The argparse type of a command's input file (a mission, a vehicle, a profile, a spec): the file
    resolve_config finds, else the path as given, which the command then refuses naming it."""
    try:
        return resolve_config(value)
    except FileNotFoundError:
        return Path(os.fspath(value))
