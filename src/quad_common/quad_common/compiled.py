"""`njit`: numba's nopython compiler for the per-physics-step kernels (eq. 6, mixer, RK4), or the identity.

The kernels are plain Python over float64 arrays and scalars, so the same source runs compiled (numba
installed: machine code, cached on disk so a new process loads instead of recompiling) or interpreted
(numba missing, or NUMBA_DISABLE_JIT=1): one implementation of the physics either way.

numba's cache checks only the file that defines a function, not the kernels it calls from other files
(simulator.py inlines onboard_attitude.py, mixer.py and rigid_body.py). So the cache lives in a folder named by a
hash of every kernel file of these packages (NUMBA_CACHE_DIR, unless set already): an edit anywhere
recompiles instead of loading stale machine code.
"""

import contextlib
import fcntl
import hashlib
import importlib.util
import os
from pathlib import Path

import numpy as np

from quad_common.paths import cache_dir

KERNEL_PACKAGES = ('quad_common', 'quad_sim')


def _kernel_sources_hash() -> str:
    digest = hashlib.sha256()
    for package in KERNEL_PACKAGES:
        spec = importlib.util.find_spec(package)
        for folder in (spec.submodule_search_locations or []) if spec else []:
            for path in sorted(Path(folder).glob('*.py')):
                text = path.read_bytes()
                if b'@njit' in text:
                    digest.update(path.name.encode() + text)
    return digest.hexdigest()[:16]


def _cache_dir() -> str:
    return str(cache_dir() / f'numba-{_kernel_sources_hash()}')


JIT_ENABLED = os.environ.get('NUMBA_DISABLE_JIT', '0') in ('', '0')   # numba reads it once, at its import, as here

if 'NUMBA_CACHE_DIR' not in os.environ and JIT_ENABLED:
    try:
        os.environ['NUMBA_CACHE_DIR'] = _cache_dir()
    except OSError:  # unreadable sources or home: numba's default cache place (next to the sources)
        pass

def _import_numba():
    """numba, imported without `coverage` when no coverage run is active: numba.misc.coverage_support imports
    it if installed (0.3-0.8 s of every node's start on the 2-core machine) only to report compiled lines to a
    coverage run, and a run already measuring has imported coverage itself.

    Its array typing (numba.np.arraymath, which loading a cached kernel imports) is imported here too, without
    scipy's BLAS: it imports scipy.linalg (~0.3 s of the simulator's start) only to choose how a compiled 1-D
    np.dot runs, and no kernel calls np.dot, np.linalg or `@` (quad_sim's kernels: plain loops over floats).
    Without it such a dot would be numba's own loop; matrix products and np.linalg import scipy when compiled."""
    import sys
    hidden = [name for name in ('coverage', 'scipy.linalg.cython_blas') if name not in sys.modules]
    for name in hidden:
        sys.modules[name] = None  # import NAME -> ImportError inside numba only
    try:
        import numba
        import numba.np.arraymath  # noqa: F401
    except ImportError:  # pragma: no cover - numba is pinned in requirements.txt
        return None
    finally:
        for name in hidden:
            del sys.modules[name]
    return numba


numba = _import_numba()

COMPILED = numba is not None


def njit(function):
    """Compile `function` with numba (nopython, cached, no GIL held) where numba is installed."""
    if numba is None:
        return function
    return numba.njit(cache=True, nogil=True)(function)


def compile_lock_path(cache_folder: str, source_folder: str) -> str:
    """The lock file of one source folder's kernels in a cache folder (numba keeps each source folder's apart)."""
    digest = hashlib.sha256(os.path.abspath(source_folder).encode()).hexdigest()[:16]
    return os.path.join(cache_folder, f'compile-{digest}.lock')


@contextlib.contextmanager
def one_compiler(source_folder: str):
    """Held while a process loads the kernels of source_folder (Simulator.warm_up): an exclusive lock, so that
    processes started together (a test run's graphs, a fleet's nodes) on a cache without those kernels compile them
    one at a time, the first one compiling (~12 s of CPU on the 2-core machine) and the others loading what it wrote
    (~0.15 s), not each compiling the same kernels at once. Nothing to hold where nothing is compiled or cached."""
    folder = os.environ.get('NUMBA_CACHE_DIR')
    if numba is None or not JIT_ENABLED or not folder:
        yield
        return
    try:
        os.makedirs(folder, exist_ok=True)
        lock = open(compile_lock_path(folder, source_folder), 'a')
    except OSError:   # an unwritable cache: numba compiles without caching anyway
        yield
        return
    with lock:
        fcntl.flock(lock, fcntl.LOCK_EX)   # released at close, or by the kernel when the holder dies
        yield


def float_array(values) -> np.ndarray:
    """values as a C-contiguous float64 array (no copy when they already are one): the kernels' argument type."""
    return np.ascontiguousarray(values, dtype=np.float64)
