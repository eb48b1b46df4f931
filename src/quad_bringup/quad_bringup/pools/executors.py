"""Where the runs of a sweep or a tune execute: a local process pool (all cores, nothing to set up) or, with
`--scheduler ADDRESS`, a Dask distributed cluster. Both hand results back as they finish, so the caller can
append each row at once (an interrupt keeps every finished run). Scheduling is the engines' own.
"""

import concurrent.futures
import os
import signal
import sys
import time
from collections.abc import Callable, Iterable, Iterator


def _worker_start():
    """Pool workers leave Ctrl-C to the parent, which cancels what has not started and keeps what finished, and
    die with their forkserver, which dies with the sweep (quad_bringup.pools.pool_lifeline)."""
    from quad_bringup.pools.pool_lifeline import die_with_parent

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    die_with_parent()


class LocalExecutor:
    """concurrent.futures.ProcessPoolExecutor with one worker per core (or `workers`)."""

    def __init__(self, workers: int | None = None):
        import multiprocessing

        from quad_bringup.pools.pool_lifeline import POOL_PARENT_VARIABLE

        if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
            raise RuntimeError(f'--workers {workers} refused: must be an integer >= 1')
        self.workers = workers or os.cpu_count() or 1
        # forkserver, not fork: a parent that has run rclpy (Fast DDS threads) would hand its children a
        # half-copied middleware, and a `--graph` run in such a child hangs at its first ROS call
        context = multiprocessing.get_context('forkserver')
        os.environ[POOL_PARENT_VARIABLE] = str(os.getpid())
        context.set_forkserver_preload(['__main__', 'quad_bringup.pools.pool_lifeline'])
        self._pool = concurrent.futures.ProcessPoolExecutor(self.workers, initializer=_worker_start,
                                                            mp_context=context)
        self.description = f'local process pool, {self.workers} workers'

    def map_unordered(self, fn: Callable, items: Iterable, *args) -> Iterator:
        """Yields (index, result or exception) in completion order."""
        futures = {self._pool.submit(fn, item, *args): i for i, item in enumerate(items)}
        try:
            for future in concurrent.futures.as_completed(futures):
                yield futures[future], future.exception() or future.result()
        finally:
            for future in futures:
                future.cancel()

    def close(self):
        self._pool.shutdown(wait=True, cancel_futures=True)


def _tcp_refused(address: str, timeout_s: float = 5.0) -> str | None:
    """Why a tcp:// scheduler address takes no connection (refused, unreachable), or None (it does, or the
    address is not tcp://): Dask's Client retries a closed port until its 20 s timeout; the user hears at once."""
    import socket
    from urllib.parse import urlsplit

    parts = urlsplit(address)
    if parts.scheme != 'tcp':
        return None
    try:
        host, port = parts.hostname, parts.port
    except ValueError as exc:
        return str(exc)
    if host is None or port is None:
        return None
    try:
        socket.create_connection((host, port), timeout=timeout_s).close()
    except OSError as exc:
        return exc.strerror or str(exc)
    return None


class DaskExecutor:
    """A dask.distributed Client on an existing scheduler (`dask scheduler`, `dask worker ADDRESS`)."""

    def __init__(self, address: str):
        try:
            from dask.distributed import Client
        except ImportError as exc:
            raise RuntimeError(f'--scheduler needs dask[distributed] ({exc}); rerun `make venv`') from None
        if '://' not in address or not address.split('://', 1)[1]:
            raise RuntimeError(f'--scheduler {address!r} refused: give the scheduler\'s address, e.g. '
                               'tcp://10.0.0.1:8786')
        refused = _tcp_refused(address)
        if refused:
            raise RuntimeError(f'--scheduler {address}: cannot connect ({refused})')
        try:
            self._client = Client(address, timeout='20s')
        except (OSError, TimeoutError, ValueError) as exc:
            raise RuntimeError(f'--scheduler {address}: cannot connect ({exc})') from None
        n = sum(w.get('nthreads', 1) for w in self._client.scheduler_info()['workers'].values())
        self.workers = n
        self.description = f'Dask cluster {address}, {n} worker threads'

    def map_unordered(self, fn: Callable, items: Iterable, *args) -> Iterator:
        from dask.distributed import as_completed

        items = list(items)
        futures = self._client.map(fn, items, *[[a] * len(items) for a in args], pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        try:
            for future in as_completed(futures):
                yield index[future.key], future.exception() or future.result()
        finally:
            self._client.cancel(futures)

    def close(self):
        self._client.close()


def make_executor(scheduler: str | None = None, workers: int | None = None):
    return DaskExecutor(scheduler) if scheduler else LocalExecutor(workers)


class Progress:
    """One self-rewriting line on stderr: done/total, rate, ETA, failures (a plain line every 5 s off a tty)."""

    def __init__(self, total: int, label: str, already: int = 0, stream=sys.stderr):
        self.total, self.label, self.already, self.stream = total, label, already, stream
        self.done = self.failed = 0
        self.start = time.monotonic()
        self._last = 0.0
        self._tty = stream.isatty()

    def update(self, failed: bool = False):
        self.done += 1
        self.failed += bool(failed)
        now = time.monotonic()
        if now - self._last >= (0.2 if self._tty else 5.0) or self.done == self.total:
            self._last = now
            self._write(now)

    def _write(self, now):
        elapsed = now - self.start
        rate = self.done / elapsed if elapsed > 0 else 0.0
        left = (self.total - self.done) / rate if rate > 0 else float('inf')
        eta = f'{int(left // 60)}:{int(left % 60):02d}' if left != float('inf') else '?'
        width = 24
        filled = int(width * self.done / self.total) if self.total else width
        line = (f'{self.label} [{"#" * filled}{"." * (width - filled)}] {self.done}/{self.total} '
                f'{rate:.1f}/s ETA {eta}' + (f', {self.failed} failed' if self.failed else '')
                + (f' ({self.already} done before)' if self.already else ''))
        self.stream.write(('\r' + line + '\033[K') if self._tty else line + '\n')
        if self._tty and self.done == self.total:
            self.stream.write('\n')
        self.stream.flush()

    def close(self):
        if self._tty and self.done != self.total:
            self.stream.write('\n')
            self.stream.flush()
