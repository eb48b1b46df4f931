"""fly's ROS domain: a domain whose lock file is free but which already holds a graph started without
it (a real bridge, someone's ros2 launch) is passed over, naming its nodes."""

import subprocess
import sys

import pytest

from quad_common import domains
from quad_common.ros.domain_probe import foreign_nodes

NODE = ('import rclpy, sys, time; rclpy.init(); n = rclpy.create_node("foreign_bridge"); print("up", flush=True); '
        'time.sleep(120)')


def test_a_domain_holding_a_foreign_graph_is_passed_over(monkeypatch):
    with domains.isolated_domain() as (domain, env):
        foreign = subprocess.Popen([sys.executable, '-c', NODE], env=env, stdout=subprocess.PIPE, text=True)
    try:
        assert foreign.stdout.readline().strip() == 'up'
        monkeypatch.setattr(domains, '_DOMAINS', range(domain, domain + 1))   # only that domain is left
        with domains.isolated_domain() as (taken, _):   # without the probe: taken, as before
            assert taken == domain
        with pytest.raises(RuntimeError, match=rf'in use by graphs not started by quadflight: {domain} '
                                               r'\(/foreign_bridge\)'):
            with domains.isolated_domain(probe=lambda d: foreign_nodes(d, 10.0)):
                pass
    finally:
        foreign.kill()
        foreign.wait()
    with domains.isolated_domain(probe=lambda d: foreign_nodes(d, 0.5)) as (taken, _):
        assert taken == domain   # free again once the graph is gone
