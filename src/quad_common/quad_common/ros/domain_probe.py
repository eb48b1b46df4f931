"""Who is already in a ROS domain: quad_common.domains.isolated_domain's probe for `fly` and fleets."""

import time

from quad_common.domains import domain_ports_holders

PROBE_WAIT_S = 0.5   # where the socket tables are not readable: how long a probe node waits for discovery


def domain_occupants(domain: int) -> list[str]:
    """The processes holding `domain`'s RTPS ports (quad_common.domains.domain_ports_holders: at once, and whatever
    the load), else, where the kernel does not show them, the nodes a probe node sees within PROBE_WAIT_S."""
    holders = domain_ports_holders(domain)
    return foreign_nodes(domain, PROBE_WAIT_S) if holders is None else holders


def foreign_nodes(domain: int, wait_s: float) -> list[str]:
    """Nodes already in ROS domain `domain` (a graph someone started without our lock files, e.g. a real bridge),
    seen by a probe node for wait_s (Fast DDS answers a new participant at once)."""
    import rclpy  # here: loading rcl starts threads, and fly forks node_host while it has none (pools.forked)

    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain)
    try:
        node = rclpy.create_node('quadflight_domain_probe', context=context, start_parameter_services=False,
                                 enable_rosout=False)
        deadline = time.monotonic() + wait_s
        while True:
            names = [f'{ns.rstrip("/")}/{n}' for n, ns in node.get_node_names_and_namespaces()
                     if n != 'quadflight_domain_probe']
            if names or time.monotonic() >= deadline:
                return sorted(names)
            time.sleep(0.05)
    finally:
        context.try_shutdown()
