"""HotPathExecutor: a single-threaded executor that serves a node's per-tick entities through a lean wait set.

Why: rclpy's executor rebuilds its wait set from every entity of every node (parameter services, QoS event
handlers, all timers and subscriptions) and runs one callback per spin_once: ~0.2-0.4 ms of Python per callback on
the 2-core machine, several callbacks per lockstep tick, most of the graph's wall time. Here the few entities of
the tick (`hot`) wake the loop and all of them that are ready run in one pass; everything else (services,
parameters, slow timers, other subscriptions) is served in a slow pass every `slow_period_s` of wall time, or every
SLOW_SHARE_BOUND times as long as its last pass took when that is longer (a host of many nodes): a probe of those
entities (_SlowProbe) that serves the ready timers itself and hands anything else to the stock executor, whose own
pass also runs every STOCK_PERIOD_S.
"""

import inspect
import time
from collections.abc import Callable

from rclpy.exceptions import InvalidHandle
from rclpy.executors import (
    ConditionReachedException,
    ExternalShutdownException,
    ShutdownException,
    SingleThreadedExecutor,
    TimeoutException,
)
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.subscription import Subscription

# The rclpy release whose internals this module uses (rclpy_implementation.WaitSet, Executor._guard and
# _sigint_gc, a subscription handle's take_message, Subscription._callback_type, wait_for_ready_callbacks) and
# against which quad_common.ros.cdr's hand-packed layouts were checked; src/quad_common/test/test_rclpy_pin.py fails,
# naming both versions, when the installed rclpy is another one or a layout no longer matches: re-check both there,
# then move the pin.
CHECKED_RCLPY_VERSION = '7.1.5'


def installed_rclpy_version() -> str:
    """The installed rclpy's release: its Python distribution's version (PyPI wheels), else the <version> of its
    package.xml in the ament index (a ROS install)."""
    import importlib.metadata
    import re

    try:
        return importlib.metadata.version('rclpy')
    except importlib.metadata.PackageNotFoundError:
        from ament_index_python.packages import get_package_share_directory

        xml = open(f'{get_package_share_directory("rclpy")}/package.xml').read()
        return re.search(r'<version>\s*([^<\s]+)', xml).group(1)


# Wall time between passes over the other entities: their callbacks wait at most this. A pass rebuilds rclpy's
# whole wait set (~1-2 ms of Python on the 2-core machine): every 20 ms that was ~30 % of the lockstep graph's
# time (bench_sim graph RTF, interleaved runs: 6.5-7.1x at 20 ms, 9.6-10.0x at 100 ms).
SLOW_PERIOD_S = 0.1
# ... and at least this many times as long as the last pass took: a pass costs O(entities) (a fleet host of 64
# vehicles: ~1,000 entities, 20-40 ms), so at a fixed period it would take a growing share of the loop (the fleet's
# stepping time grew as N^2); bounded, it stays under ~1 / SLOW_SHARE_BOUND of it.
SLOW_SHARE_BOUND = 10.0
# The stock executor's own pass (every entity, the QoS event handlers too) at least this often (wall time); between
# its passes a probe of the rest serves the ready timers (HotPathExecutor._spin_ready_others).
STOCK_PERIOD_S = 1.0
HOT_PASSES_BEFORE_SLOW = 3   # zero-wait hot passes before a slow pass (each serves what the one before made ready)


def now_ns(clock) -> int:
    """clock.now().nanoseconds without the Time object (rclpy's Clock.now builds and checks one, ~3 us on the
    2-core machine; a lockstep controller reads its clock twice a step): the clock's rcl handle, held in use as
    Clock.now holds it."""
    handle = clock.handle
    with handle:
        return handle.get_now().nanoseconds


def _take_message(sub):
    msg_info = sub.handle.take_message(sub.msg_type, sub.raw)
    return None if msg_info is None else msg_info[0]


def _hold(handles) -> list | None:
    """Every handle held in use for a pass, until _release (why: HotPathExecutor._spin_hot); None, holding none, when
    one is destroyed already."""
    held = []
    try:
        for handle in handles:
            handle.__enter__()
            held.append(handle)
    except InvalidHandle:
        _release(held)
        return None
    return held


def _release(held: list):
    for handle in reversed(held):
        handle.__exit__(None, None, None)


class _HotSet:
    """The hot entities of a pass, looked up once (an entity's handle is a Python property; its pointer a call)
    while they stay the same: (pointer, subscription, handle, takes MessageInfo) per subscription, (timer, handle)
    per timer, (pointer, guard) per guard condition, every handle to hold in use, and the wait set."""

    def __init__(self, subscriptions, timers, guards, wakers, context):
        self.subscriptions = [(s.handle.pointer, s, s.handle,
                               s._callback_type is Subscription.CallbackType.WithMessageInfo) for s in subscriptions]
        self.subscription_index = {}   # pointer -> its first place in the list
        for k, entry in enumerate(self.subscriptions):
            self.subscription_index.setdefault(entry[0], k)
        self.timers = [(t, t.handle) for t in timers]
        self.guards = [(g.handle.pointer, g) for g in guards]
        self.subscription_handles = [h for _, _, h, _ in self.subscriptions]
        self.timer_handles = [h for _, h in self.timers]
        self.guard_handles = [g.handle for g in (*wakers, *guards)]
        self.handles = (*self.subscription_handles, *self.timer_handles, *self.guard_handles)
        self.wait_set = _rclpy.WaitSet(len(subscriptions), len(self.guard_handles), len(timers), 0, 0, 0,
                                       context.handle)


class _SlowProbe:
    """One wait set over the subscriptions, timers, clients, services and guard conditions of the executor's nodes
    that are not hot (the hot passes serve those), made again only when they change (the stock executor builds one
    per pass over every entity, ~9 ms of Python at a host of 33 nodes, most of it their ~600 QoS event handlers).
    `serve` waits on it without blocking and serves the ready timers when nothing else is ready (plain callbacks,
    served as the hot path serves its own); it returns None, serving nothing, when anything else is (the stock pass
    serves it, in its order). The event handlers are not in it: the stock pass serves them every STOCK_PERIOD_S."""

    def __init__(self, nodes, hot: set, context):
        self.timers = [t for n in nodes for t in n.timers if t not in hot]
        self.guards = [g for n in nodes for g in n.guards if g not in hot]   # nor the executor's wake-ups
        self.plain_timers = all(not inspect.iscoroutinefunction(t.callback) for t in self.timers)
        self.subscription_handles = [s.handle for n in nodes for s in n.subscriptions if s not in hot]
        self.timer_handles = [t.handle for t in self.timers]
        self.client_handles = [c.handle for n in nodes for c in n.clients]
        self.service_handles = [s.handle for n in nodes for s in n.services]
        self.guard_handles = [g.handle for g in self.guards]
        self.handles = (*self.subscription_handles, *self.timer_handles, *self.client_handles,
                        *self.service_handles, *self.guard_handles, context.handle)
        self.wait_set = _rclpy.WaitSet(len(self.subscription_handles), len(self.guard_handles), len(self.timers),
                                       len(self.client_handles), len(self.service_handles), 0, context.handle)

    def serve(self) -> int | None:
        """The number of timers served, or None (nothing served) where the stock pass must serve."""
        if not self.plain_timers or any(timer._executor_event for timer in self.timers):
            return None   # a coroutine, or a stock handler still pending: the stock executor's own business
        in_use = _hold(self.handles)
        if in_use is None:   # an entity being destroyed (its node is going away): the stock pass copes
            return None
        try:
            return self._serve()
        finally:
            _release(in_use)

    def _serve(self) -> int | None:
        wait_set = self.wait_set
        wait_set.clear_entities()
        for handle in self.subscription_handles:
            wait_set.add_subscription(handle)
        for handle in self.client_handles:
            wait_set.add_client(handle)
        for handle in self.service_handles:
            wait_set.add_service(handle)
        for handle in self.timer_handles:
            wait_set.add_timer(handle)
        for handle in self.guard_handles:
            wait_set.add_guard_condition(handle)
        wait_set.wait(0)
        guards = set(wait_set.get_ready_entities('guard_condition'))
        if guards:   # taken by this wait (rcl): triggered again for the stock pass to see
            for guard, handle in zip(self.guards, self.guard_handles):
                if handle.pointer in guards:
                    guard.trigger()
            return None
        if any(wait_set.get_ready_entities(kind) for kind in ('subscription', 'client', 'service')):
            return None
        ready, served = set(wait_set.get_ready_entities('timer')), 0
        for timer, handle in zip(self.timers, self.timer_handles):
            if handle.pointer in ready and handle.is_timer_ready():   # rcl: a cancelled timer is reported ready
                handle.call_timer()
                timer.callback()
                served += 1
        return served


class HotPathExecutor(SingleThreadedExecutor):
    def __init__(self, hot: Callable[[], tuple], *, slow_period_s: float = SLOW_PERIOD_S, context=None,
                 take: Callable | None = None, takes_per_pass: int = 1):
        """hot() -> (subscriptions, timers) or (subscriptions, timers, guard conditions) of the tick; asked before
        every wait, as a node may replace them. Their callbacks take the message, or the message and its MessageInfo
        when they take two arguments as rclpy's own executor decides (none for a guard condition), and are plain
        functions (no coroutines). take(subscription) -> message or None replaces the plain take of a hot
        subscription of the first kind (quad_bridge.setpoint_source: with the publisher's GID). takes_per_pass:
        the messages taken from a ready subscription in one pass, until its queue is empty (1: one per pass, so
        messages of different subscriptions are served in turn; a recorder takes its backlog in one wake-up instead
        of one wake-up and one wait-set pass per message)."""
        super().__init__(context=context)
        self._hot = hot
        self._take = take or _take_message
        self._slow_period_s = slow_period_s
        self._takes_per_pass = max(int(takes_per_pass), 1)
        self._next_slow_s = 0.0
        self._hot_set_key = self._hot_set_made = None
        self._probe_key = self._probe = None
        self._next_stock_s = 0.0

    def spin_once(self, timeout_sec: float | None = None) -> None:
        """Wait up to timeout_sec (None: until the next slow pass) for a hot entity and run every ready one; no wait
        when the slow pass's turn ran any callback (the caller looks first: a lockstep's setpoints may be in)."""
        if self._is_shutdown or not self._context.ok():
            return
        now_s = time.monotonic()
        served = False
        if now_s >= self._next_slow_s:
            # The hot entities ready now first, and what their callbacks made ready (a controller's setpoint for a
            # hosted simulator): the stock executor would serve each with a pass over every entity of every node.
            for _ in range(HOT_PASSES_BEFORE_SLOW):
                if not self._spin_hot(0.0):
                    break
                served = True
            served = self._spin_ready_others() or served
            slow_s = time.monotonic() - now_s
            self._next_slow_s = now_s + max(self._slow_period_s, SLOW_SHARE_BOUND * slow_s)
        wait_s = 0.0 if served else self._next_slow_s - now_s
        if timeout_sec is not None and timeout_sec >= 0:
            wait_s = min(wait_s, timeout_sec)
        self._spin_hot(wait_s)

    def _spin_hot(self, wait_s: float) -> bool:
        """One wait of up to wait_s for the hot entities, then every ready one's callback; whether any was.

        Every handle in the wait set is held in use for the pass (as rclpy's own executor does): rcl would free an
        entity destroyed from another thread under the wait (a segfault); held, its destruction waits for the
        pass to end. An entity already destroyed (its node is going away) ends the pass with nothing served."""
        subscriptions, timers, *guards = self._hot()
        guards = guards[0] if guards else ()
        wakers = (self._guard, self._sigint_gc)
        if None in wakers:   # shut down
            return False
        try:
            hot = self._hot_set(subscriptions, timers, guards, wakers)
        except InvalidHandle:
            return False
        in_use = _hold(hot.handles)
        if in_use is None:
            return False
        try:
            return self._serve_hot(wait_s, hot)
        finally:
            _release(in_use)

    def _serve_hot(self, wait_s, hot) -> bool:
        wait_set = hot.wait_set
        wait_set.clear_entities()   # rcl_wait empties it: the entities are added again before every wait
        for handle in hot.subscription_handles:
            wait_set.add_subscription(handle)
        for handle in hot.timer_handles:
            wait_set.add_timer(handle)
        for handle in hot.guard_handles:   # add_node / shutdown wake-ups, SIGINT, then the node's guards
            wait_set.add_guard_condition(handle)
        wait_set.wait(max(int(wait_s * 1e9), 0))
        if not self._context.ok():
            raise ExternalShutdownException()
        ready = wait_set.get_ready_entities('subscription')
        served = bool(ready)
        if ready:   # the ready ones in the hot list's order (/clock first), not a look at every one
            index = hot.subscription_index
            for k in sorted({index[pointer] for pointer in ready}):
                _, sub, handle, with_info = hot.subscriptions[k]
                for _ in range(self._takes_per_pass):
                    if with_info:  # callback(msg, MessageInfo)
                        taken = handle.take_message(sub.msg_type, sub.raw)
                        if taken is None:
                            break
                        sub.callback(*taken)
                        continue
                    msg = self._take(sub)
                    if msg is None:
                        break
                    sub.callback(msg)
        if hot.guards:  # a worker thread's result (e.g. a decoded trajectory)
            ready = set(wait_set.get_ready_entities('guard_condition'))
            for pointer, gc in hot.guards:
                if pointer in ready:
                    served = True
                    gc.callback()
        for timer, handle in hot.timers:  # after the subscriptions: a /clock message may just have made a sim-time
            if handle.is_timer_ready():   # timer due
                served = True
                handle.call_timer()
                timer.callback()
        return served

    def _hot_set(self, subscriptions, timers, guards, wakers) -> '_HotSet':
        """The hot entities' handles and wait set, made again only when the entities change."""
        key = (tuple(subscriptions), tuple(timers), tuple(guards), wakers)
        if key != self._hot_set_key:
            self._hot_set_key = key
            self._hot_set_made = _HotSet(subscriptions, timers, guards, wakers, self._context)
        return self._hot_set_made

    def _spin_ready_others(self) -> bool:
        """Every callback ready now that the hot passes do not serve: the stock executor's pass (every entity, hot
        ones included) every STOCK_PERIOD_S, else a probe first (_SlowProbe): ready timers only, the usual case (the
        nodes' diagnostics), are served there; anything else ready (a service request, a non-hot message, a guard
        condition) hands the pass to the stock executor's. Whether any callback ran."""
        now_s = time.monotonic()
        if now_s < self._next_stock_s:
            served = self._probe_set(self.get_nodes()).serve()
            if served is not None:
                return served > 0
        self._next_stock_s = now_s + STOCK_PERIOD_S
        return self._spin_stock_ready() > 0

    def _probe_set(self, nodes) -> '_SlowProbe':
        hot = self._hot_set_key or ((), (), ())
        key = (tuple((node, tuple(node.subscriptions), tuple(node.timers), tuple(node.clients),
                      tuple(node.services), tuple(node.guards), tuple(node.waitables)) for node in nodes), hot[:3])
        if key != self._probe_key:
            self._probe_key = key
            self._probe = _SlowProbe(nodes, {*hot[0], *hot[1], *hot[2]}, self._context)
        return self._probe

    def _spin_stock_ready(self) -> int:
        """Every callback the stock executor finds ready now (one wait-set pass), hot ones included; how many ran."""
        ran = 0
        while True:
            try:
                handler, _, _ = self.wait_for_ready_callbacks(0)
            except (TimeoutException, ShutdownException, ConditionReachedException):
                return ran
            handler()
            ran += 1
            if handler.exception() is not None:
                raise handler.exception()
