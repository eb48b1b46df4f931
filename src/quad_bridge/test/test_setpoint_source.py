"""The setpoint source gate: a GID is admitted only when the graph names its node setpoint_source and
no other publisher claims that name; unknown GIDs ask the graph at most every GRAPH_REFRESH_MIN_S."""

from types import SimpleNamespace

from quad_bridge.setpoint_source import (
    GRAPH_REFRESH_MIN_S,
    HELD_MAX_AGE_S,
    HOLD,
    NAME_WAIT_S,
    REFUSE,
    SetpointSource,
    SourceGate,
    fully_qualified,
)

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


def test_an_unnamed_publisher_is_held_not_refused_and_asks_the_graph_at_most_every_period():
    graph = Graph()
    gate = _gate(graph)
    assert [gate.decide(CONTROLLER) for _ in range(50)] == [HOLD] * 50
    assert graph.asked == 1 and gate.counts()['refused_source'] == 0 and gate.counts()['held_unnamed'] == 50
    graph.pubs.append(('/ns/position_controller', list(CONTROLLER)))   # discovery names it
    graph.now_s += GRAPH_REFRESH_MIN_S
    assert gate.admit(CONTROLLER) and graph.asked == 2


def test_a_publisher_the_graph_never_names_is_refused_after_the_name_wait():
    graph = Graph(('/_NODE_NAMESPACE_UNKNOWN_/_NODE_NAME_UNKNOWN_', list(INTRUDER)))
    gate = _gate(graph)
    assert gate.decide(INTRUDER) == HOLD
    graph.now_s += NAME_WAIT_S
    assert gate.decide(INTRUDER) == REFUSE and gate.counts()['refused_source'] == 1


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


class Log:
    def __init__(self):
        self.lines = []

    def warn(self, text, **_):
        self.lines.append(text)


def _source(graph, queue):
    """SetpointSource over a stand-in graph (node_name, namespace, gid per publisher) and take (queue of (raw, gid))."""
    def infos(topic):
        return [SimpleNamespace(node_name=name.rpartition('/')[2], node_namespace=name.rpartition('/')[0] or '/',
                                endpoint_gid=gid) for name, gid in graph.pubs]
    node = SimpleNamespace(get_publishers_info_by_topic=infos)
    log = Log()
    source = SetpointSource(node, SimpleNamespace(topic_name='/ns/cmd/attitude_thrust'), '/ns/position_controller', log,
                            clock=lambda: graph.now_s, take=lambda sub: queue.pop(0) if queue else None)
    return source, log


def test_the_controllers_first_setpoints_wait_for_its_name_then_the_newest_flies_unrefused():
    """The controller's first setpoints arrive while the graph says _NODE_NAME_UNKNOWN_: none is flown, none refused;
    once the graph names it, its newest held setpoint is released (without a further setpoint) and the next ones fly."""
    graph = Graph(('/_NODE_NAMESPACE_UNKNOWN_/_NODE_NAME_UNKNOWN_', list(CONTROLLER)))
    queue = [(b'sp1', CONTROLLER), (b'sp2', CONTROLLER)]
    source, log = _source(graph, queue)
    assert source.take_one(None) == (True, None) and source.take_one(None) == (True, None)
    assert source.release() is None                    # still unnamed
    graph.pubs[0] = ('/ns/position_controller', list(CONTROLLER))
    graph.now_s += GRAPH_REFRESH_MIN_S
    assert source.release() == b'sp2'                  # named: its newest, at the next look at the graph
    assert source.release() is None
    queue.append((b'sp3', CONTROLLER))
    assert source.take_one(None) == (True, b'sp3')
    counts = source.counts()
    assert counts['refused_source'] == 0 and counts['held_unnamed'] == 2 and not log.lines


def test_a_held_setpoint_is_never_flown_for_another_node_nor_when_stale():
    graph = Graph(('/_NODE_NAMESPACE_UNKNOWN_/_NODE_NAME_UNKNOWN_', list(INTRUDER)))
    source, log = _source(graph, [(b'bad', INTRUDER)])
    assert source.take_one(None) == (True, None)
    graph.pubs[0] = ('/ns/intruder', list(INTRUDER))
    graph.now_s += GRAPH_REFRESH_MIN_S
    assert source.release() is None and 'only /ns/position_controller may command' in log.lines[-1]
    late = Graph(('/_NODE_NAMESPACE_UNKNOWN_/_NODE_NAME_UNKNOWN_', list(CONTROLLER)))
    source, _ = _source(late, [(b'old', CONTROLLER)])
    assert source.take_one(None) == (True, None)
    late.pubs[0] = ('/ns/position_controller', list(CONTROLLER))
    late.now_s += HELD_MAX_AGE_S + GRAPH_REFRESH_MIN_S
    assert source.release() is None                    # named too late for that setpoint to be flown
