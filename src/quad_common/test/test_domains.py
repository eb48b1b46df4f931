"""fly's ROS domain: a domain whose lock file is free but which already holds a graph started without
it (a real bridge, someone's ros2 launch) is passed over, naming who holds it."""

import os
import socket
import subprocess
import sys

import pytest

from quad_common import domains
from quad_common.ros.domain_probe import domain_occupants, foreign_nodes

NODE = ('import rclpy, sys, time; rclpy.init(); n = rclpy.create_node("foreign_bridge"); print("up", flush=True); '
        'time.sleep(120)')


@pytest.fixture
def foreign_graph():
    """(domain, pid) of a node started in a domain without its lock file, alive until the test ends."""
    with domains.isolated_domain() as (domain, env):
        foreign = subprocess.Popen([sys.executable, '-c', NODE], env=env, stdout=subprocess.PIPE, text=True)
    try:
        assert foreign.stdout.readline().strip() == 'up'
        yield domain, foreign.pid
    finally:
        foreign.kill()
        foreign.wait()


def test_a_domain_holding_a_foreign_graph_is_passed_over(monkeypatch, foreign_graph):
    domain, pid = foreign_graph
    monkeypatch.setattr(domains, '_DOMAINS', range(domain, domain + 1))   # only that domain is left
    with domains.isolated_domain() as (taken, _):   # without the probe: taken, as before
        assert taken == domain
    # at once (no discovery wait): the node's process holds the domain's RTPS ports
    with pytest.raises(RuntimeError, match=rf'in use by graphs not started by quadflight: {domain} \(pid {pid} '):
        with domains.isolated_domain(probe=domain_occupants):
            pass
    # the discovery probe (where the kernel's socket tables cannot be read) sees the node by name
    with pytest.raises(RuntimeError, match=rf'in use by graphs not started by quadflight: {domain} '
                                           r'\(/foreign_bridge\)'):
        with domains.isolated_domain(probe=lambda d: foreign_nodes(d, 10.0)):
            pass


def test_the_domain_is_free_again_once_the_graph_is_gone(monkeypatch):
    with domains.isolated_domain() as (domain, env):
        subprocess.run([sys.executable, '-c', NODE.replace('time.sleep(120)', 'pass')], env=env, check=True,
                       capture_output=True)
    monkeypatch.setattr(domains, '_DOMAINS', range(domain, domain + 1))
    with domains.isolated_domain(probe=domain_occupants) as (taken, _):
        assert taken == domain


def test_any_socket_on_a_domain_port_holds_the_domain_and_names_its_process():
    """Every RTPS port of the domain counts, its first and its last, and none of the next or previous domain's."""
    with domains.isolated_domain() as (domain, _):
        first = domains.RTPS_PORT_BASE + domains.RTPS_DOMAIN_GAIN * domain
        last = first + domains.RTPS_DOMAIN_GAIN - 1
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as a, \
                socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as b:
            a.bind(('127.0.0.1', first))
            b.bind(('127.0.0.1', last))
            holders = domains.domain_ports_holders(domain)
            assert [h.rpartition(', ')[2] for h in holders] == [f'UDP {first}', f'UDP {last}'], holders
            assert all(h.startswith(f'pid {os.getpid()} (') and 'python' in h for h in holders), holders
            for neighbour in (domain - 1, domain + 1):
                assert not any(f'pid {os.getpid()} ' in h for h in domains.domain_ports_holders(neighbour))
        assert domains.domain_ports_holders(domain) == []


def test_without_socket_tables_the_probe_asks_discovery(monkeypatch):
    from quad_common.ros import domain_probe

    monkeypatch.setattr(domains, '_UDP_TABLES', ('/nonexistent/udp',))
    assert domains.domain_ports_holders(1) is None
    asked = []
    monkeypatch.setattr(domain_probe, 'foreign_nodes', lambda d, wait_s: asked.append((d, wait_s)) or ['/n'])
    assert domain_probe.domain_occupants(7) == ['/n'] and asked == [(7, domain_probe.PROBE_WAIT_S)]
