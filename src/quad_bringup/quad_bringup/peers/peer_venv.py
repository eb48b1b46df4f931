"""The peer libraries measured and tested beside ours (rotorpy, minsnap-trajectories) in a venv of their own,
.bench-venv at the checkout's root, made on first use, so they never enter the project's environment; made and filled
by the uv beside the project's python (scripts/bootstrap-venv installs it), which resolves and unpacks in parallel. Not
part of a flight: used by the benches and by the tests that fly a peer's plant or controller
(quad_bringup.peers.rotorpy_peer)."""

import fcntl
import os
import subprocess
import sys
from pathlib import Path

from quad_common.paths import REPO_ROOT

PEER_VENV = str(REPO_ROOT / '.bench-venv')
PEERS = ['rotorpy==3.0.0', 'minsnap-trajectories==0.3.0']
PEER_CONSTRAINTS = str(Path(__file__).resolve().with_name('peer_constraints.txt'))   # their dependencies, pinned


def peer_python() -> str:
    """Path of the peers' python, installing them the first time."""
    python = os.path.join(PEER_VENV, 'bin', 'python')
    stamp = os.path.join(PEER_VENV, '.installed')
    with open(PEER_VENV + '.lock', 'w') as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)   # one installer at a time (parallel test workers); the others wait
        if not os.path.exists(stamp) or os.path.getmtime(stamp) < os.path.getmtime(PEER_CONSTRAINTS):
            uv = project_uv()
            print(f'bench: installing {", ".join(PEERS)} into {PEER_VENV}', file=sys.stderr)
            subprocess.run([uv, 'venv', '--quiet', '--clear', '--python', sys.executable, PEER_VENV], check=True)
            # --compile-bytecode: where PYTHONDONTWRITEBYTECODE is set nothing would write it later.
            subprocess.run([uv, 'pip', 'install', '--quiet', '--compile-bytecode', '--python', python,
                            '-c', PEER_CONSTRAINTS, *PEERS], check=True)
            open(stamp, 'w').close()
    return python


def project_uv() -> str:
    """The uv beside the running python (the project venv's, installed by scripts/bootstrap-venv)."""
    uv = os.path.join(os.path.dirname(sys.executable), 'uv')
    if not os.access(uv, os.X_OK):
        raise FileNotFoundError(f"no uv beside {sys.executable}: the peers' venv is made with the uv that "
                                "scripts/bootstrap-venv installs into .venv; rerun 'make venv' (or install uv "
                                'into the environment running this)')
    return uv


def run_peer(code: str, timeout_s: float = 120.0) -> str:
    """Runs `code` in the peers' python; returns its stdout (raises on failure or timeout)."""
    return subprocess.run([peer_python(), '-c', code], capture_output=True, text=True, check=True,
                          timeout=timeout_s, env=dict(os.environ, MPLBACKEND='Agg')).stdout
