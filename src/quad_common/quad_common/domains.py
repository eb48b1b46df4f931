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

# DDSI-RTPS well-known ports (the RTPS specification's port mapping, used by every DDS vendor by default): domain d owns
# UDP ports PB + DG * d .. PB + DG * (d + 1) - 1; each participant in it binds its discovery (metatraffic) and user
# unicast ports there, PB + DG * d + 10 + 2 * participant_id and + 11
RTPS_PORT_BASE, RTPS_DOMAIN_GAIN = 7400, 250
_UDP_TABLES = ('/proc/net/udp', '/proc/net/udp6')

_LOCK_DIR = os.path.join(tempfile.gettempdir(), 'quadflight-ros-domains')
_DOMAINS = range(1, 101)  # Fast DDS port mapping is valid for 0..232; stay well inside it
FASTDDS_PROFILE = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'fastdds_localhost.xml')
_PROFILE_VARIABLES = ('FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE')  # Fast DDS 2.x, 3.x


@contextmanager
def isolated_domain(probe=None):
    """Yields (domain_id, env) with env a copy of os.environ set for that domain.

    Also puts the discovery profile into os.environ (unless one is set): participants this process creates
    afterwards announce as the children do (Fast DDS reads the profile at its first participant). probe(domain)
    -> who is in it (quad_common.ros.domain_probe.domain_occupants): a domain whose lock is free but which already
    holds participants, a graph started without our lock files (a real bridge), is passed over.
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


def domain_ports_holders(domain: int) -> list[str] | None:
    """Who holds a UDP port of `domain`'s RTPS range on this machine, e.g. ['pid 1234 (python3 -m bridge), UDP 8660']:
    a participant in that domain, whatever its vendor or discovery range, holds one for as long as it lives, so
    this needs no discovery wait and misses none on a loaded machine. [] when nobody does; None where the
    kernel's socket tables are not readable (not Linux)."""
    low = RTPS_PORT_BASE + RTPS_DOMAIN_GAIN * domain
    ports = {}   # socket inode -> port
    for table in _UDP_TABLES:
        try:
            with open(table) as f:
                rows = f.read().splitlines()[1:]
        except OSError:
            return None
        for row in rows:
            fields = row.split()
            port = int(fields[1].rpartition(':')[2], 16)
            if low <= port < low + RTPS_DOMAIN_GAIN:
                ports[fields[9]] = port
    if not ports:
        return []
    holders = _socket_owners(set(ports))
    return sorted({f'{holders.get(inode, "a process of another user")}, UDP {port}' for inode, port in ports.items()})


def _socket_owners(inodes: set[str]) -> dict[str, str]:
    """socket inode -> 'pid N (command)', for the processes whose descriptors this user may read."""
    owners = {}
    for pid in filter(str.isdigit, os.listdir('/proc')):
        try:
            for fd in os.listdir(f'/proc/{pid}/fd'):
                target = os.readlink(f'/proc/{pid}/fd/{fd}')
                if target.startswith('socket:[') and target[8:-1] in inodes:
                    with open(f'/proc/{pid}/cmdline', 'rb') as f:
                        command = f.read().replace(b'\0', b' ').decode(errors='replace').strip()[:60]
                    owners[target[8:-1]] = f'pid {pid} ({command})'
        except OSError:   # gone, or another user's
            continue
    return owners
