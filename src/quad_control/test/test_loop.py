"""ControlLoop's rules without ROS: the dt clamp, lockstep deferral, engagement and pause/resume, the hold point, the
start-step refusal, plan start and end, and the dead controller, with a
recording stand-in for the controller (the loop's contract is what it hands the controller and what it returns)."""

import numpy as np
import pytest

from quad_common.sampled_trajectory import SampledTrajectory
from quad_common.types import AttitudeSetpoint, State
from quad_control.loop import CONTROLLER_FAILED, ControlLoop
from quad_control.plugins import ControllerFailed
from quad_control.position import Saturation

RATE_HZ = 100.0
PERIOD_NS = 10_000_000


class Recorder:
    """Records each update's (state, reference, dt_s) and answers a level hover setpoint."""

    def __init__(self, fail_with=None):
        self.calls, self.resets, self.fail_with = [], 0, fail_with

    def update(self, state, ref, dt_s):
        if self.fail_with is not None:
            raise self.fail_with
        self.calls.append((state, ref, dt_s))
        return AttitudeSetpoint(quaternion=np.array([0.0, 0.0, 0.0, 1.0]), specific_force_mps2=9.81,
                                body_rates=np.zeros(3)), Saturation()

    def reset(self):
        self.resets += 1


def _state(position=(0.0, 0.0, 1.0)):
    return State(position=np.array(position, float), velocity=np.zeros(3), quaternion=np.array([0.0, 0, 0, 1]))


def _line(start=(0.0, 0.0, 1.0), end=(1.0, 0.0, 1.0), duration_s=1.0):
    t = np.linspace(0.0, duration_s, 101)
    s = (t / duration_s)[:, None]
    delta = np.append(np.subtract(end, start), 0.0)
    pos = np.append(start, 0.0) + s * delta
    return SampledTrajectory(t, pos, np.tile(delta / duration_s, (len(t), 1)), np.zeros_like(pos))


def test_dt_is_the_time_since_the_last_setpoint_clamped_to_two_periods():
    ctl = Recorder()
    loop = ControlLoop(ctl, RATE_HZ)
    loop.set_odometry(0, _state())
    for t_ns in (0, PERIOD_NS, 2 * PERIOD_NS, 3 * PERIOD_NS + PERIOD_NS // 2, 20 * PERIOD_NS, 19 * PERIOD_NS):
        assert loop.tick(t_ns) is not None
    dts = [dt for _, _, dt in ctl.calls]
    assert dts[0] == 0.0                                   # the first tick
    assert dts[1] == pytest.approx(0.01) and dts[2] == pytest.approx(0.01)
    assert dts[3] == pytest.approx(0.015)                  # a late tick: its real interval
    assert dts[4] == pytest.approx(0.02)                   # a gap of 16.5 periods: two periods at most
    assert dts[5] == 0.0                                   # time going back: never negative


def test_lockstep_defers_a_tick_until_its_odometry_and_a_newer_tick_supersedes_it():
    ctl = Recorder()
    loop = ControlLoop(ctl, RATE_HZ, lockstep=True)
    loop.set_odometry(0, _state())
    assert loop.tick(PERIOD_NS) is None                    # odometry of t = 0 only: deferred
    assert loop.tick(2 * PERIOD_NS) is None                # superseded by the newer tick
    assert loop.counts['superseded_ticks'] == 1 and loop.counts['deferred_ticks'] == 2
    out = loop.set_odometry(2 * PERIOD_NS, _state((0.0, 0.0, 1.1)))
    assert out is not None and out.t_ns == 2 * PERIOD_NS
    assert len(ctl.calls) == 1 and ctl.calls[0][0].position[2] == pytest.approx(1.1)


def test_before_engagement_the_reference_follows_the_vehicle_and_the_plan_starts_after_the_engage_delay():
    ctl = Recorder()
    loop = ControlLoop(ctl, RATE_HZ, engaged=False, engage_delay_s=0.5, max_start_step_m=0.5)
    loop.set_trajectory(0, _line())
    loop.set_odometry(0, _state((0.1, 0.0, 1.0)))
    tick = loop.tick(PERIOD_NS)
    assert np.allclose(tick.reference.position, [0.1, 0.0, 1.0])     # hover where it is
    loop.set_engaged(10 * PERIOD_NS, True)
    assert ctl.resets == 1
    held = loop.tick(20 * PERIOD_NS)                                  # 0.2 s: before the plan's re-based start
    assert np.allclose(held.reference.position, [0.1, 0.0, 1.0])
    started = loop.tick(60 * PERIOD_NS + PERIOD_NS)                   # 0.1 s + 0.5 s delay, one period in
    assert started.reference.position[0] == pytest.approx(0.01, abs=1e-6)
    assert loop.mode(60 * PERIOD_NS) == 'tracking'


def test_a_plan_starting_too_far_from_the_vehicle_is_refused_and_the_hold_kept():
    faults = []
    loop = ControlLoop(Recorder(), RATE_HZ, max_start_step_m=0.5, on_fault=faults.append)
    loop.set_odometry(0, _state((0.0, 0.0, 1.0)))
    loop.tick(0)
    loop.set_trajectory(PERIOD_NS, _line(start=(0.6, 0.0, 1.0)))
    tick = loop.tick(PERIOD_NS)
    assert np.allclose(tick.reference.position, [0.0, 0.0, 1.0])
    assert loop.counts['refused_start_steps'] == 1 and 'max_start_step_m' in faults[0]
    loop.set_trajectory(2 * PERIOD_NS, _line(start=(0.5, 0.0, 1.0)))   # exactly at the limit: taken
    assert loop.tick(2 * PERIOD_NS).reference.position[0] == pytest.approx(0.5)


def test_a_controller_refusal_is_a_fault_and_no_setpoint():
    faults = []
    loop = ControlLoop(Recorder(fail_with=ValueError('non-finite state')), RATE_HZ, on_fault=faults.append)
    loop.set_odometry(0, _state())
    assert loop.tick(0) is None
    assert loop.counts['control_errors'] == 1 and 'non-finite state' in faults[0]


def test_the_hold_point_is_anchored_once_and_not_moved_by_later_odometry_or_a_refused_plan():
    loop = ControlLoop(Recorder(), RATE_HZ, max_start_step_m=0.5)
    loop.set_odometry(0, _state((0.0, 0.0, 1.0)))
    loop.tick(0)
    loop.set_odometry(PERIOD_NS, _state((0.3, 0.0, 1.2)))
    assert np.allclose(loop.tick(PERIOD_NS).reference.position, [0.0, 0.0, 1.0])
    loop.set_trajectory(2 * PERIOD_NS, _line(start=(5.0, 0.0, 1.0)))
    assert np.allclose(loop.tick(2 * PERIOD_NS).reference.position, [0.0, 0.0, 1.0])
    assert loop.mode(2 * PERIOD_NS) == 'hold (no trajectory)'


def test_taking_a_plan_resets_the_controller_and_after_its_end_the_reference_is_its_final_point():
    ctl = Recorder()
    loop = ControlLoop(ctl, RATE_HZ)
    loop.set_odometry(0, _state())
    loop.set_trajectory(PERIOD_NS, _line(duration_s=1.0))
    assert np.allclose(loop.tick(0).reference.position, [0.0, 0.0, 1.0]) and ctl.resets == 0
    assert loop.tick(PERIOD_NS).reference.position[0] == pytest.approx(0.0) and ctl.resets == 1
    assert loop.tick(50 * PERIOD_NS).reference.position[0] == pytest.approx(0.49)
    assert np.allclose(loop.tick(500 * PERIOD_NS).reference.position, [1.0, 0.0, 1.0])
    assert loop.mode(500 * PERIOD_NS) == 'hold (trajectory ended)'


def test_a_dead_controller_is_never_called_again_and_no_tick_produces_a_setpoint():
    faults = []
    ctl = Recorder(fail_with=ControllerFailed('raised'))
    loop = ControlLoop(ctl, RATE_HZ, on_fault=faults.append)
    loop.set_odometry(0, _state())
    assert loop.tick(0) is None
    ctl.fail_with = None
    assert loop.tick(PERIOD_NS) is None and ctl.calls == []
    assert loop.counts['controller_failures'] == 1 and len(faults) == 1 and faults[0].startswith(CONTROLLER_FAILED)


def test_lockstep_waits_for_engagement_and_for_a_plan_when_asked():
    ctl = Recorder()
    loop = ControlLoop(ctl, RATE_HZ, lockstep=True, wait_for_trajectory=True, engaged=False)
    loop.set_odometry(PERIOD_NS, _state())
    assert loop.tick(PERIOD_NS) is None                      # not engaged
    assert loop.set_engaged(PERIOD_NS, True) is None         # engaged, but no plan yet
    out = loop.set_trajectory(PERIOD_NS, _line())
    assert out is not None and out.t_ns == PERIOD_NS and len(ctl.calls) == 1


def test_the_end_of_a_hand_over_pauses_the_plan_and_the_next_engagement_resumes_it_after_the_delay():
    loop = ControlLoop(Recorder(), RATE_HZ, engage_delay_s=0.5, max_start_step_m=10.0)
    loop.set_odometry(0, _state())
    loop.set_trajectory(0, _line(duration_s=1.0))
    loop.tick(0)
    loop.set_odometry(30 * PERIOD_NS, _state((0.3, 0.0, 1.0)))
    assert loop.tick(30 * PERIOD_NS).reference.position[0] == pytest.approx(0.3)
    loop.set_engaged(40 * PERIOD_NS, False)                  # paused at 0.4 s of the plan
    loop.set_odometry(60 * PERIOD_NS, _state((0.2, 0.1, 1.0)))
    assert np.allclose(loop.tick(60 * PERIOD_NS).reference.position, [0.2, 0.1, 1.0])   # follows the vehicle
    loop.set_engaged(100 * PERIOD_NS, True)
    assert np.allclose(loop.tick(120 * PERIOD_NS).reference.position, [0.2, 0.1, 1.0])  # hold, re-anchored
    resumed = loop.tick(150 * PERIOD_NS)                     # 1.0 s + 0.5 s: the plan resumes at 0.4 s
    assert resumed.reference.position[0] == pytest.approx(0.4)
