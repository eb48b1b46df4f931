"""The setpoint source gate (issue 27.1): a GID is admitted only when the graph names its node setpoint_source and
no other publisher claims that name; unknown GIDs ask the graph at most every GRAPH_REFRESH_MIN_S."""

from quad_bridge.setpoint_source import GRAPH_REFRESH_MIN_S, SourceGate, fully_qualified

CONTROLLER, INTRUDER, IMPOSTOR = b'c' * 16, b'i' * 16, b'x' * 16


class Graph:
    def __init__(self, *pubs):
        self.pubs, self.asked, self.now_s = list(pubs), 0, 0.0

    def publishers(self):
        self.asked += 1
        return list(self.pubs)


def _gate(graph):
    return SourceGate('/ns/position_controller', graph.publishers, clock=lambda: graph.now_s)


def test_only_the_named_node_is_admitted_and_others_are_counted_by_name():
    graph = Graph(('/ns/position_controller', list(CONTROLLER)), ('/ns/intruder', list(INTRUDER)))
    gate = _gate(graph)
    assert gate.admit(CONTROLLER) and not gate.admit(INTRUDER) and not gate.admit(INTRUDER)
    counts = gate.counts()
    assert counts['refused_source'] == 2 and counts['refused_publishers'] == '/ns/intruder (2)'
    assert 'only /ns/position_controller may command' in gate.why_refused(INTRUDER)


def test_a_second_publisher_claiming_the_name_refuses_both():
    graph = Graph(('/ns/position_controller', list(CONTROLLER)))
    gate = _gate(graph)
    assert gate.admit(CONTROLLER)
    graph.pubs.append(('/ns/position_controller', list(IMPOSTOR)))
    graph.now_s += GRAPH_REFRESH_MIN_S
    assert not gate.admit(IMPOSTOR) and not gate.admit(CONTROLLER)
    assert '2 publishers claim the node name' in gate.why_refused(CONTROLLER)
    graph.pubs.pop()   # the impostor left
    graph.now_s += GRAPH_REFRESH_MIN_S
    gate.refresh()
    assert gate.admit(CONTROLLER)


def test_an_unknown_publisher_is_refused_and_asks_the_graph_at_most_every_period():
    graph = Graph()
    gate = _gate(graph)
    assert not any(gate.admit(CONTROLLER) for _ in range(50))
    assert graph.asked == 1 and gate.counts()['refused_publishers'] == 'unknown publisher (50)'
    graph.pubs.append(('/ns/position_controller', list(CONTROLLER)))   # discovery names it
    graph.now_s += GRAPH_REFRESH_MIN_S
    assert gate.admit(CONTROLLER) and graph.asked == 2


def test_relative_source_names_are_in_the_bridges_namespace():
    assert fully_qualified('position_controller', '/') == '/position_controller'
    assert fully_qualified('position_controller', '/a/b') == '/a/b/position_controller'
    assert fully_qualified('/x/ctl', '/a') == '/x/ctl' and fully_qualified('', '/a') == ''


def test_a_publisher_discovered_before_its_node_name_is_admitted_once_the_name_arrives():
    """Fast DDS names an endpoint's node only when ros_discovery_info arrives (CI: refused for 90 s before)."""
    graph = Graph(('/_NODE_NAMESPACE_UNKNOWN_/_NODE_NAME_UNKNOWN_', list(CONTROLLER)))
    gate = _gate(graph)
    assert not gate.admit(CONTROLLER)
    graph.pubs[0] = ('/ns/position_controller', list(CONTROLLER))
    assert not gate.admit(CONTROLLER) and graph.asked == 1   # within the refresh period: not asked again
    graph.now_s += GRAPH_REFRESH_MIN_S
    assert gate.admit(CONTROLLER) and graph.asked == 2
