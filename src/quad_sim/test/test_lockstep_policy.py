"""The lockstep policy without ROS: setpoint acceptance, per-step waits, re-publication and advancing, on a fake
wall clock."""

from quad_sim import lockstep_policy as lp

PERIOD_NS = 10_000_000  # 0.01 s


def test_setpoint_one_period_ahead_is_taken_and_beyond_is_refused():
    t_ns = 1_000_000_000
    assert lp.classify_setpoint(t_ns + PERIOD_NS, -1, t_ns, PERIOD_NS) == lp.TAKE
    assert lp.classify_setpoint(t_ns + PERIOD_NS + 1, -1, t_ns, PERIOD_NS) == lp.FUTURE
    assert lp.classify_setpoint(t_ns + 2 * PERIOD_NS, -1, t_ns, PERIOD_NS) == lp.FUTURE
    assert lp.classify_setpoint(t_ns + 5 * PERIOD_NS + 1, -1, t_ns, PERIOD_NS) == lp.FUTURE


def test_older_setpoint_is_ignored_and_same_stamp_taken():
    assert lp.classify_setpoint(90, 100, 100, PERIOD_NS) == lp.OLDER
    assert lp.classify_setpoint(100, 100, 100, PERIOD_NS) == lp.TAKE


def test_step_timeout_before_first_setpoint_after_loss_and_with_no_publisher():
    assert lp.setpoint_timeout_s(0.5, 3, False, True) == 0.5
    assert lp.setpoint_timeout_s(0.5, 0, False, True) == lp.STARTUP_REPUBLISH_S
    assert lp.setpoint_timeout_s(0.05, 0, False, True) == 0.05
    assert lp.setpoint_timeout_s(0.5, 3, True, True) == lp.LOST_STEP_TIMEOUT_S
    assert lp.setpoint_timeout_s(0.5, 3, True, False) == 0.0


def test_advance_needs_setpoint_history_or_controller_for_every_vehicle():
    asked = []

    def present(answer, name):
        return lambda: asked.append(name) or answer

    t_k = 100
    assert lp.may_advance([(t_k, 0, present(False, 'a'))], t_k)
    assert lp.may_advance([(-1, 2, present(False, 'b'))], t_k)
    assert lp.may_advance([(-1, 0, present(True, 'c'))], t_k)
    assert not lp.may_advance([(-1, 0, present(False, 'd')), (t_k, 1, present(True, 'e'))], t_k)
    assert asked == ['c', 'd']  # the graph is asked only for vehicles without a setpoint


def test_wait_expires_vehicles_at_their_deadlines_on_a_fake_clock():
    wait = lp.SetpointWait(['slow', 'lost'], {'slow': 10.5, 'lost': 10.02}, now_s=10.0)
    assert abs(wait.wake_in_s(10.0) - 0.02) < 1e-12
    assert wait.expire(10.01) == []
    assert wait.expire(10.02) == ['lost']
    assert wait.waiting == ['slow']
    assert abs(wait.wake_in_s(10.05) - 0.05) < 1e-12  # the re-publication at 10.1 comes before 10.5
    wait.answered(lambda v: v == 'slow')
    assert wait.waiting == []


def test_republication_once_per_interval():
    wait = lp.SetpointWait(['v'], {'v': 100.0}, now_s=0.0)
    assert not wait.republish_due(0.05)
    assert wait.republish_due(lp.STARTUP_REPUBLISH_S)
    assert not wait.republish_due(lp.STARTUP_REPUBLISH_S + 0.05)
    assert wait.republish_due(2 * lp.STARTUP_REPUBLISH_S)


def test_vehicle_counts_future_setpoints_and_a_loss_once_until_a_setpoint_comes_back():
    v = lp.VehicleLockstep()
    t_ns = 10 * PERIOD_NS
    assert v.classify(t_ns + 2 * PERIOD_NS, t_ns, PERIOD_NS) == lp.FUTURE and v.future_setpoints == 1
    assert not v.missed_deadline() and not v.controller_lost   # before the first setpoint: start-up, not a loss
    assert v.classify(t_ns, t_ns, PERIOD_NS) == lp.TAKE
    assert v.applied(t_ns) and not v.applied(t_ns)              # True for the first only
    assert v.classify(t_ns - 1, t_ns, PERIOD_NS) == lp.OLDER and v.future_setpoints == 1
    assert v.missed_deadline() and v.controller_lost
    assert not v.missed_deadline()                               # one warning per loss
    v.applied(t_ns + PERIOD_NS)
    assert not v.controller_lost and v.setpoints_received == 3 and v.setpoint_stamp_ns == t_ns + PERIOD_NS


def test_vehicle_timeout_asks_the_graph_only_once_lost():
    v = lp.VehicleLockstep()
    asked = []

    def publisher(answer):
        return lambda: asked.append(answer) or answer

    assert v.timeout_s(0.5, publisher(False)) == lp.STARTUP_REPUBLISH_S
    v.applied(0)
    assert v.timeout_s(0.5, publisher(False)) == 0.5 and asked == []
    v.missed_deadline()
    assert v.timeout_s(0.5, publisher(True)) == lp.LOST_STEP_TIMEOUT_S
    assert v.timeout_s(0.5, publisher(False)) == 0.0
    assert asked == [True, False]


def test_odometry_steps_count_distinct_stamps():
    v = lp.VehicleLockstep()
    for t_ns in (0, 0, 0, PERIOD_NS, 2 * PERIOD_NS, 2 * PERIOD_NS):   # step 0 re-published for late joiners
        v.odometry_published(t_ns)
    assert v.steps_published == 3 and v.last_odom_ns == 2 * PERIOD_NS


def test_followers_behind_and_a_reordered_ack_does_not_go_back():
    f = lp.Followers(['recorder', 'monitor'])
    assert f.behind(0) == ['recorder', 'monitor']
    f.ack('recorder', 50)
    f.ack('recorder', 30)
    f.ack('monitor', 40)
    assert f.acked_ns == {'recorder': 50, 'monitor': 40}
    assert f.behind(45) == ['monitor'] and f.behind(40) == []
    assert lp.Followers([]).behind(10**12) == []
    assert lp.Followers.step_target_ns(100, 400) == 0 and lp.Followers.step_target_ns(500, 400) == 100


def test_follower_wait_republishes_only_before_the_first_setpoint_and_warns_once_per_interval():
    wait = lp.FollowerWait(now_s=0.0)
    assert not wait.republish_due(0.05, started=False)
    assert not wait.republish_due(lp.STARTUP_REPUBLISH_S, started=True)
    assert wait.republish_due(lp.STARTUP_REPUBLISH_S, started=False)
    assert not wait.republish_due(lp.STARTUP_REPUBLISH_S + 0.05, started=False)
    assert not wait.warn_due(lp.FOLLOWER_WARN_S)
    assert wait.warn_due(lp.FOLLOWER_WARN_S + 0.01)
    assert not wait.warn_due(lp.FOLLOWER_WARN_S + 1.0)
    assert wait.warn_due(2 * lp.FOLLOWER_WARN_S + 0.02)


def test_drain_goes_on_while_acks_advance_and_stops_after_a_stall():
    acked = {'recorder': 10}
    watch = lp.DrainWatch(acked, now_s=0.0)
    assert not watch.stalled(acked, lp.DRAIN_STALL_S)
    acked = {'recorder': 20}
    assert not watch.stalled(acked, lp.DRAIN_STALL_S + 5.0)        # progress: the stall clock restarts
    assert not watch.stalled(acked, 2 * lp.DRAIN_STALL_S + 5.0)
    assert watch.stalled(acked, 2 * lp.DRAIN_STALL_S + 5.1)


def test_realtime_pacer_runs_rtf_times_wall_time_in_whole_steps():
    step_ns = 1_000_000
    pacer = lp.RealtimePacer(now_s=100.0, sim_time_ns=0)
    assert pacer.steps_due(100.0105, 1.0, 0, step_ns) == 10          # 10.5 ms: 10 whole steps
    assert pacer.steps_due(100.0111, 1.0, 10 * step_ns, step_ns) == 1  # the half step carried over
    assert pacer.steps_due(100.0211, 2.0, 11 * step_ns, step_ns) == 20  # rtf 2: 10 ms of wall time, 20 ms of sim
    assert pacer.steps_due(100.0221, 0.5, 40 * step_ns, step_ns) == 0  # ahead of the target: none


def test_run_clock_keeps_the_longest_wait_only_while_stepping():
    clock = lp.RunClock(wall_s=10.0, sim_ns=0)
    assert clock.real_time_factor(10.0, 0) == 0.0
    assert clock.real_time_factor(12.0, 1_000_000_000) == 0.5
    clock.waited('setpoints', 3.0, 0, ['cf1'])                        # start-up: not counted
    assert clock.longest == {} and not clock.stepping
    clock.advancing(11.0, 0, 1.0)
    clock.advancing(11.5, 5, 2.0)                                     # only the first advance counts
    clock.waited('setpoints', 0.2, 10, ['cf1'])
    clock.waited('setpoints', 0.1, 20, ['cf2'])
    clock.waited('followers', 0.3, 30, [])
    assert clock.longest == {'setpoints': (0.2, 10, ['cf1']), 'followers': (0.3, 30, [])}
    assert clock.summary(13.0, 4_000_000_000, 1.5) == (4.0, 2.0, 0.5)
