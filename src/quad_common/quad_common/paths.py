"""Where config files named in parameters are found: the path as given, else under the repository root."""

from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[3]  # src/quad_common/quad_common/paths.py (symlink-install too)


def resolve_config(path) -> Path:
    """An absolute path or one relative to the working directory if it exists, else relative to the repo root.

    Raises FileNotFoundError naming the path when neither exists.
    """
    p = Path(path).expanduser()
    if p.is_absolute() or p.exists():
        if not p.exists():
            raise FileNotFoundError(f'{path}: no such file')
        return p
    candidate = REPO_ROOT / p
    if not candidate.exists():
        raise FileNotFoundError(f'{path}: no such file (looked in {Path.cwd()} and {REPO_ROOT})')
    return candidate
