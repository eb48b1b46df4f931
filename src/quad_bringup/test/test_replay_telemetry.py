"""replay.telemetry_of: the odometry age the twin's controller flies, from what the flight's controller reported
where it did (its diagnostics, inside the plan's window), else from the bag's record - stamp times."""

import numpy as np
import pytest

from quad_bringup.analysis.metrics import Flight
from quad_bringup.offline.replay import telemetry_of

WALL_S = 1.8e9                  # a vehicle's bag: wall-clock stamps


def _flight(record_delay_s=0.030, period_s=0.02, n=500, start_s=WALL_S, **extra):
    t = start_s + period_s * np.arange(n)
    zeros = np.zeros((n, 3))
    return Flight(odom_t=t, position=zeros, velocity=zeros, euler=zeros,
                  odom_record_ns=np.round((t + record_delay_s) * 1e9).astype(np.int64), **extra)


def _at(s):
    return int(round(s * 1e9))


def test_the_age_the_controller_reported_inside_the_window_is_flown_without_a_hold():
    reports = [(_at(WALL_S + 1.0), 36.0), (_at(WALL_S + 2.0), 38.0), (_at(WALL_S + 3.0), 40.0),
               (_at(WALL_S + 9.5), 500.0)]              # after the window (a landing's stale odometry)
    age_s, period_s, source = telemetry_of(_flight(controller_odom_age=reports), (WALL_S, WALL_S + 3.0))
    assert age_s == pytest.approx(0.038)
    assert period_s == 0.0                                # the reported age holds the wait for the next sample
    assert 'controller' in source


def test_without_reports_the_bags_record_minus_stamp_and_half_its_period():
    age_s, period_s, source = telemetry_of(_flight(record_delay_s=0.030), (WALL_S, WALL_S + 3.0))
    assert age_s == pytest.approx(0.030, abs=1e-6)
    assert period_s == pytest.approx(0.02)
    assert 'record - stamp' in source


def test_reports_outside_the_window_are_not_taken():
    reports = [(_at(WALL_S + 20.0), 500.0)]
    age_s, _, source = telemetry_of(_flight(controller_odom_age=reports), (WALL_S, WALL_S + 3.0))
    assert age_s == pytest.approx(0.030, abs=1e-6) and 'record - stamp' in source


def test_a_simulators_bag_is_fresh_whatever_it_reports():
    flight = _flight(start_s=10.0, controller_odom_age=[(_at(11.0), 0.0)])
    assert telemetry_of(flight, (10.0, 13.0))[:2] == (0.0, 0.0)
