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
