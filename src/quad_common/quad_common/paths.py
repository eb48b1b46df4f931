"""Where config files named in parameters are found: the path as given, else in the installed share directory
(share/quad_bringup/config, installed by quad_bringup's setup.py, found through the ament index), else in the
source tree of a checkout."""

import os
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[3]  # src/quad_common/quad_common/paths.py (symlink-install too)
SHARE_PACKAGE = 'quad_bringup'                   # the package whose share directory holds config/


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
    """Where a relative config path (e.g. config/vehicles/crazyflie.yaml) is looked for, in order."""
    roots = [d for d in (share_dir(),) if d is not None]
    if (REPO_ROOT / 'config').is_dir():
        roots.append(REPO_ROOT)
    return roots


def resolve_config(path) -> Path:
    """An absolute path or one relative to the working directory if it exists, else under config_roots().

    Raises FileNotFoundError naming the path and every place looked in when none has it.
    """
    p = Path(os.fspath(path)).expanduser()
    if p.is_absolute() or p.exists():
        if not p.exists():
            raise FileNotFoundError(f'{path}: no such file')
        return p
    roots = config_roots()
    for root in roots:
        if (root / p).exists():
            return root / p
    places = ', '.join(str(d) for d in [Path.cwd(), *roots])
    raise FileNotFoundError(f'{path}: no such file (looked in {places})')
