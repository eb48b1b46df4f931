"""Isolation of ROS graphs (`quadflight fly`'s and the tests'): each gets a ROS_DOMAIN_ID nobody else on the
machine holds.

Domains are claimed with an exclusive lock file, so parallel or repeated runs (two `make test`
at once, colcon testing packages in parallel) never share a graph. Discovery is localhost-only, with the
Fast DDS profile fastdds_localhost.xml (participants announce every 0.2 s, not 3 s) unless one is set already.
"""

import fcntl
import os
import tempfile
from contextlib import contextmanager

_LOCK_DIR = os.path.join(tempfile.gettempdir(), 'quadflight-ros-domains')
_DOMAINS = range(1, 101)  # Fast DDS port mapping is valid for 0..232; stay well inside it
FASTDDS_PROFILE = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'fastdds_localhost.xml')
_PROFILE_VARIABLES = ('FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE')  # Fast DDS 2.x, 3.x


@contextmanager
def isolated_domain(probe=None):
    """Yields (domain_id, env) with env a copy of os.environ set for that domain.

    Also puts the discovery profile into os.environ (unless one is set): participants this process creates
    afterwards announce as the children do (Fast DDS reads the profile at its first participant). probe(domain)
    -> node names (quad_common.ros.domain_probe.foreign_nodes): a domain whose lock is free but which already holds
    nodes, a graph started without our lock files (a real bridge), is passed over.
    """
    if not any(os.environ.get(v) for v in _PROFILE_VARIABLES):
        os.environ.update(dict.fromkeys(_PROFILE_VARIABLES, FASTDDS_PROFILE))
    os.makedirs(_LOCK_DIR, exist_ok=True)
    start = os.getpid() % len(_DOMAINS)
    occupied = []
    for i in range(len(_DOMAINS)):
        domain = _DOMAINS[(start + i) % len(_DOMAINS)]
        f = open(os.path.join(_LOCK_DIR, f'{domain}.lock'), 'w')
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            f.close()
            continue
        others = probe(domain) if probe else []
        if others:
            occupied.append(f'{domain} ({", ".join(others[:3])})')
            f.close()
            continue
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
        try:
            yield domain, env
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)
            f.close()
        return
    raise RuntimeError(f'no free ROS domain id in {_DOMAINS}: too many test graphs running' +
                       (f'; in use by graphs not started by quadflight: {", ".join(occupied)}' if occupied else ''))
