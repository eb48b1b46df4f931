"""The flight harness (quad_bringup.offline.harness): the telemetry models deliver what they promise (age, rate, bursts,
stamps), and `fly` runs position_controller's ControlLoop rules on the plant: a lockstep flight ends when the
controller dies, a free-running one keeps the last setpoint through a tick without one, the plant holds level
until the first odometry, done / fault / a stopped simulation end the flight where they happen."""

import math

import numpy as np
import pytest

from quad_bringup.offline.harness import DelayLine, FixedAge, Fresh, Mocap, fly, idle
from quad_common.types import GRAVITY_MPS2, AttitudeSetpoint, Reference, State
from quad_control.loop import ControlLoop
from quad_control.plugins import ControllerFailed
from quad_control.pose_state import PoseStateFilter
from quad_control.position import Saturation
from quad_sim.mocap import MocapConfig
from quad_sim.simulator import SimulationStopped

PERIOD_NS = 10_000_000


class Plant:
    """x = the number of periods advanced (the truth's and the odometry's x); records every command."""

    def __init__(self, stop_after=None):
        self.periods, self.stop_after, self.commands = 0, stop_after, []

    @property
    def state(self):
        return State(position=np.array([float(self.periods), 0.0, 0.0]))

    def observed(self):
        return self.state

    def command(self, setpoint):
        self.commands.append((self.periods, setpoint))

    def advance(self, dt_s):
        assert math.isclose(dt_s, PERIOD_NS * 1e-9)
        if self.stop_after is not None and self.periods >= self.stop_after:
            raise SimulationStopped('speed limit', self.periods * 0.01, [self.periods, 0, 0])
        self.periods += 1


class Controller:
    """Commands a specific force equal to the x it saw; raises `fail` at the ticks in fail_at (1-based calls)."""
    name = 'probe'

    def __init__(self, fail_at=(), fail=ValueError):
        self.calls, self.seen, self.fail_at, self.fail = 0, [], set(fail_at), fail

    def update(self, state, ref, dt_s):
        self.calls += 1
        if self.calls in self.fail_at:
            raise self.fail(f'refused at call {self.calls}')
        self.seen.append(float(state.position[0]))
        return AttitudeSetpoint(quaternion=np.array([0.0, 0.0, 0.0, 1.0]),
                                specific_force_mps2=5.0 + state.position[0]), Saturation()

    def reset(self):
        pass


class Point:
    duration_s = 0.0

    def reference(self, t_s):
        return Reference()


def _loop(controller, lockstep=False):
    loop = ControlLoop(controller, 100.0, lockstep=lockstep)
    loop.set_trajectory(0, Point())
    return loop


def test_fresh_telemetry_is_the_odometry_of_that_many_ticks_before_stamped_with_the_tick():
    controller = Controller()
    flown = fly(_loop(controller, lockstep=True), Plant(), Fresh(latency_periods=2), 6)
    assert controller.seen == [0.0, 0.0, 0.0, 1.0, 2.0, 3.0]
    assert [stamp for stamp, _ in flown.odometry] == [k * PERIOD_NS for k in range(6)]


def test_fixed_age_interpolates_between_the_ticks_states():
    controller = Controller()
    flown = fly(_loop(controller), Plant(), FixedAge(0.015), 5)
    assert controller.seen == pytest.approx([0.0, 0.0, 0.5, 1.5, 2.5])
    assert [stamp for stamp, _ in flown.odometry] == [k * PERIOD_NS - 15_000_000 for k in range(5)]


def test_delay_line_samples_every_second_tick_and_delivers_it_late_once():
    controller = Controller()
    flown = fly(_loop(controller), Plant(), DelayLine(0.02, every_periods=2, stamp_shift_s=0.02), 9)
    # measured at ticks 0, 2, 4, 6: delivered 2 ticks later, stamped at arrival, each taken once
    assert [(stamp, state.position[0]) for stamp, state in flown.odometry] == [
        (2 * PERIOD_NS, 0.0), (4 * PERIOD_NS, 2.0), (6 * PERIOD_NS, 4.0), (8 * PERIOD_NS, 6.0)]
    # the controller runs every tick on the newest: nothing before tick 2
    assert controller.seen == [0.0, 0.0, 2.0, 2.0, 4.0, 4.0, 6.0]


def test_delay_line_bursts_release_the_odometry_only_at_their_instants():
    steady, bursty = Controller(), Controller()
    fly(_loop(steady), Plant(), DelayLine(0.0, initial=State()), 200)
    fly(_loop(bursty), Plant(), DelayLine(0.0, burst_s=0.05, seed=3, initial=State()), 200)
    lags = np.arange(200) - np.array(bursty.seen)
    assert steady.seen == list(np.arange(200.0))
    assert lags.min() == 0 and 3 <= lags.max() <= 5     # held up to the 50 ms burst
    assert 0.5 < np.mean(lags) < 3.0


def test_the_plant_holds_level_until_the_first_odometry_then_flies_the_controller():
    plant = Plant()
    fly(_loop(Controller()), plant, DelayLine(0.03), 6)
    first, hover = plant.commands[0]
    assert first == 0 and hover.specific_force_mps2 == GRAVITY_MPS2
    np.testing.assert_allclose(hover.quaternion, idle(plant.state).quaternion)
    assert [k for k, _ in plant.commands] == [0, 3, 4, 5]    # idle once, then each tick's setpoint
    assert [sp.specific_force_mps2 for _, sp in plant.commands[1:]] == [5.0, 6.0, 7.0]


def test_a_free_running_flight_keeps_the_last_setpoint_through_a_tick_without_one():
    plant = Plant()
    flown = fly(_loop(Controller(fail_at={3})), plant, Fresh(), 5)
    assert flown.stopped is None and flown.final is not None
    assert flown.ticks[2] is None
    assert [k for k, _ in plant.commands] == [0, 1, 3, 4]   # nothing new at tick 2: the plant flies tick 1's


def test_a_lockstep_flight_ends_when_the_controller_dies():
    controller = Controller(fail_at={4}, fail=ControllerFailed)
    flown = fly(_loop(controller, lockstep=True), Plant(), Fresh(), 10)
    assert flown.stopped.startswith('controller failed at t = 0.030 s'), flown.stopped
    assert len(flown.ticks) == 4 and flown.final is None


def test_done_fault_and_a_stopped_simulation_end_the_flight_where_they_happen():
    done = fly(_loop(Controller()), Plant(), Fresh(), 10, done=lambda t_ns, truth: truth.position[0] >= 3)
    assert done.done and done.stopped is None and len(done.truth) == 4 and done.final is None
    fault = fly(_loop(Controller()), Plant(), Fresh(), 10,
                fault=lambda t_ns, truth: 'fell' if truth.position[0] >= 2 else None)
    assert fault.stopped == 'fell' and len(fault.truth) == 3
    stopped = fly(_loop(Controller()), Plant(stop_after=4), Fresh(), 10)
    assert 'speed limit' in stopped.stopped and len(stopped.ticks) == 5
    full = fly(_loop(Controller()), Plant(), Fresh(), 10, start_ns=5 * PERIOD_NS)
    t_s, states = full.track()
    assert full.final_ns == 15 * PERIOD_NS and t_s[-1] == pytest.approx(0.15) and states[-1].position[0] == 10


def test_mocap_delivers_each_frame_late_through_the_pose_filter():
    controller = Controller()
    telemetry = Mocap(MocapConfig(rate_hz=50.0, latency_s=0.02), PoseStateFilter(0.001, 5.0, 0.2))
    flown = fly(_loop(controller), Plant(), telemetry, 9)
    assert [stamp for stamp, _ in flown.odometry] == [0, 2 * PERIOD_NS, 4 * PERIOD_NS, 6 * PERIOD_NS]
    assert flown.odometry[0][1].position[0] == 0.0 and flown.odometry[-1][1].position[0] > 4.0  # filtered
    assert flown.odometry[-1][1].velocity[0] > 0.0
