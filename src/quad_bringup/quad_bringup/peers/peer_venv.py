"""The peer libraries measured and tested beside ours (rotorpy, minsnap-trajectories) in a venv of their own,
.bench-venv at the checkout's root, made on first use, so they never enter the project's environment. Not part of a
flight: used by the benches and by the tests that fly a peer's plant or controller (quad_bringup.peers.rotorpy_peer)."""

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
            print(f'bench: installing {", ".join(PEERS)} into {PEER_VENV}', file=sys.stderr)
            subprocess.run([sys.executable, '-m', 'venv', '--clear', PEER_VENV], check=True)
            subprocess.run([python, '-m', 'pip', 'install', '--quiet', '-c', PEER_CONSTRAINTS, *PEERS], check=True)
            open(stamp, 'w').close()
    return python


def run_peer(code: str, timeout_s: float = 120.0) -> str:
    """Runs `code` in the peers' python; returns its stdout (raises on failure or timeout)."""
    return subprocess.run([peer_python(), '-c', code], capture_output=True, text=True, check=True,
                          timeout=timeout_s, env=dict(os.environ, MPLBACKEND='Agg')).stdout
