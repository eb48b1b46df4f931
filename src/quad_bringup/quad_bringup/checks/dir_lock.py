"""One writer per output directory: an exclusive flock on DIR/.quadflight.lock (fly's run directory, a sweep's or
tune's --out), which the kernel drops when the holder ends, SIGKILL included. Imports nothing of quadflight."""

import fcntl
import os
from pathlib import Path

LOCK_NAME = '.quadflight.lock'


class DirectoryBusy(Exception):
    """Another command holds the directory's lock; str() names it (e.g. 'fly pid 1234')."""


def claim_dir(path: Path, what: str) -> int:
    """Takes PATH/LOCK_NAME's exclusive lock without waiting and writes `what pid N` into it; returns the descriptor
    that holds the lock (os.close releases it). Raises DirectoryBusy naming the holder, OSError when it cannot be
    made."""
    fd = os.open(Path(path) / LOCK_NAME, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = os.pread(fd, 200, 0).decode(errors='replace').strip() or '?'
        os.close(fd)
        raise DirectoryBusy(holder) from None
    os.ftruncate(fd, 0)
    os.pwrite(fd, f'{what} pid {os.getpid()}\n'.encode(), 0)
    return fd


def holder_of(path: Path) -> str | None:
    """Who holds PATH's lock now ('fly pid 1234'), or None; creates nothing."""
    try:
        fd = os.open(Path(path) / LOCK_NAME, os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        return None
    except BlockingIOError:
        return os.pread(fd, 200, 0).decode(errors='replace').strip() or '?'
    finally:
        os.close(fd)   # a shared lock taken goes with it
