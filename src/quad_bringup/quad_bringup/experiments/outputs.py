"""An output directory of sweep, tune or fly: checked before anything is made (a file, an unwritable place: one line,
nothing left) and held by one writer at a time: an exclusive flock on OUT/.quadflight.lock for the command's life,
which the kernel drops when the process ends, SIGKILL included."""

import os
from pathlib import Path

from quad_bringup.checks.dir_lock import DirectoryBusy, claim_dir
from quad_bringup.experiments.runs import SpecError


def check_out_dir(out: Path):
    """Raises SpecError when `out` cannot be the output directory."""
    if out.exists() and not out.is_dir():
        raise SpecError(f'--out {out}: a file, not a directory: choose another --out')
    parent = out
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise SpecError(f'--out {out}: cannot create or write it ({parent} is not a writable directory)')


class OutputDir:
    """Makes `out` and holds its lock until close(); SpecError when another command holds it."""

    def __init__(self, out, what: str):
        self.path = Path(out)
        check_out_dir(self.path)
        try:
            self.path.mkdir(parents=True, exist_ok=True)
            self._fd = claim_dir(self.path, what)
        except DirectoryBusy as busy:
            raise SpecError(f'--out {self.path}: another sweep or tune writes there now ({busy}): wait for it '
                            'or choose another --out') from None
        except OSError as exc:
            raise SpecError(f'--out {self.path}: cannot create or write it ({exc.strerror or exc})') from None

    def close(self):
        if self._fd is not None:
            os.close(self._fd)   # the lock goes with the descriptor
            self._fd = None
