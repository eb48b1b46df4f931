"""Peer libraries measured beside ours (rotorpy, minsnap-trajectories) live in their own venv,
.bench-venv, made on first use, so they never enter the project's environment."""

import fcntl
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PEER_VENV = os.path.join(ROOT, '.bench-venv')
PEERS = ['rotorpy==3.0.0', 'minsnap-trajectories==0.3.0']
PEER_CONSTRAINTS = os.path.join(ROOT, 'bench', 'peers-constraints.txt')   # their dependencies, pinned


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
