"""Feasibility before flight: each check against numbers computed here from the plan's samples, where and by
how much a plan exceeds, and the limits allocation named (and fitting) when the seed's profile does not."""

import dataclasses

import numpy as np
import pytest

from quad_common.types import GRAVITY_MPS2
from quad_common.vehicle import AttitudeGains, load_vehicle
from quad_trajectory import feasibility
from quad_trajectory.mission import DEFAULT_VEHICLE_PATH, load_mission, mission_from_dict, plan_mission, preflight
from quad_trajectory.planner import PlanOptions, plan

FIGURE8 = DEFAULT_VEHICLE_PATH.replace('vehicles/crazyflie.yaml', 'missions/figure8.yaml')


@pytest.fixture(scope='module')
def crazyflie():
    return load_vehicle(DEFAULT_VEHICLE_PATH)


def dense_needs(traj, vehicle, rate_hz=4000.0):
    """Tilt (deg) and collective thrust (N) at dense samples, written out independently of the module."""
    t = np.linspace(0, traj.duration_s, int(traj.duration_s * rate_hz) + 2)
    a = traj.evaluate(t, 2)[:, :3] + [0, 0, GRAVITY_MPS2]
    tilt = np.degrees(np.arctan2(np.linalg.norm(a[:, :2], axis=1), a[:, 2]))
    return t, tilt, vehicle.mass_kg * np.linalg.norm(a, axis=1)


def test_slow_plan_is_feasible_and_reports_its_peaks(crazyflie):
    traj = plan([[0, 0, 1], [1, 0, 1], [1, 1, 1.2]], options=PlanOptions(speed_mps=0.3)).trajectory
    report = feasibility.check(traj, crazyflie)
    assert report.ok and report.exceeded == []
    _, tilt, thrust = dense_needs(traj, crazyflie)
    assert report.peaks['tilt'] == pytest.approx(tilt.max(), abs=0.05)
    assert report.peaks['thrust_max'] == pytest.approx(thrust.max(), rel=1e-3)
    assert 'feasible on crazyflie' in report.lines()[0]


def test_tilt_exceedance_says_where_and_by_how_much(crazyflie):
    """The issue's case: figure8 at --speed 2 asks 11 m/s^2, more than the Crazyflie's 35 degrees give."""
    traj = plan_mission(load_mission(FIGURE8), speed_mps=2.0).trajectory
    report = feasibility.check(traj, crazyflie)
    tilt = next(e for e in report.exceeded if e.check == 'tilt')
    t, dense_tilt, _ = dense_needs(traj, crazyflie)
    assert tilt.value == pytest.approx(dense_tilt.max(), abs=0.2) and tilt.limit == 35.0
    assert tilt.excess == pytest.approx((dense_tilt.max() - 35.0) / 35.0, abs=0.01)
    assert abs(tilt.time_s - t[np.argmax(dense_tilt)]) < 0.05        # where: the time of the worst sample
    assert traj.breaks_s[tilt.segment] <= tilt.time_s <= traj.breaks_s[tilt.segment + 1]
    assert tilt.samples_over > 0 and 'tilt: needs 48' in str(tilt) and 'over by 13' in str(tilt)


def test_thrust_and_rotor_limits_on_a_hard_climb(crazyflie):
    """Straight up 2 m in 1 s, rest to rest: about 2.5 g peak, past thrust-to-weight 1.95."""
    traj = plan([[0, 0, 1], [0, 0, 3]], options=PlanOptions(speed_mps=2.0)).trajectory
    report = feasibility.check(traj, crazyflie)
    names = {e.check: e for e in report.exceeded}
    _, tilt, thrust = dense_needs(traj, crazyflie)
    assert names['thrust_max'].value == pytest.approx(thrust.max(), rel=5e-3)   # 32 samples a segment
    assert names['thrust_max'].limit == pytest.approx(crazyflie.thrust_max_n)
    # no moment on a straight vertical line: the busiest rotor carries a quarter of the thrust
    assert names['rotor_speed_max'].value == pytest.approx(np.sqrt(thrust.max() / 4 / crazyflie.k_eta), rel=5e-3)
    # and the stop at the top brakes at more than g: the thrust would have to point down (tilt 180 deg)
    assert names['tilt'].value == pytest.approx(180.0) and tilt.max() == pytest.approx(180.0)


def test_attitude_lag_is_the_ramp_lag_of_the_loop(crazyflie):
    assert feasibility.tilt_ramp_lag_s(crazyflie) == pytest.approx(0.015 + 300.0 / 3000.0)
    sluggish = dataclasses.replace(crazyflie, attitude_gains=AttitudeGains(kp=np.full(3, 20.0), kd=np.full(3, 30.0)))
    assert feasibility.tilt_ramp_lag_s(sluggish) == pytest.approx(0.015 + 1.5)
    traj = plan_mission(load_mission(FIGURE8), speed_mps=1.0).trajectory
    assert feasibility.check(traj, crazyflie).ok
    lagged = feasibility.check(traj, sluggish)
    assert [e.check for e in lagged.exceeded] == ['attitude_lag']   # the tilt alone (16 deg) would fit


def test_preflight_names_fastest_with_its_time_and_limits_and_both_fit(crazyflie):
    mission = load_mission(FIGURE8)
    report = preflight(mission, plan_mission(mission, speed_mps=2.0), speed_mps=2.0)
    fastest, limits = report.alternative('fastest'), report.alternative('limits')
    assert not report.ok and report.fits == 'fastest' and [a[0] for a in report.alternatives] == ['fastest', 'limits']
    assert report.planned_s < fastest[1] < limits[1]       # slower than the infeasible plan, faster than limits
    text = '\n'.join(report.lines())
    assert "the seed's sqrt profile at 2 m/s asks more than crazyflie gives" in text
    assert f'time_allocation fastest fits: {fastest[1]:.2f} s planned' in text and '--time-allocation fastest' in text
    assert 'time_allocation limits fits' in text
    for name in ('fastest', 'limits'):
        assert feasibility.check(plan_mission(mission, speed_mps=2.0, time_allocation=name).trajectory, crazyflie).ok


def test_margin_narrows_every_limit(crazyflie):
    lim = feasibility.margined_limits(crazyflie, 0.1)
    assert lim['tilt'][0] == pytest.approx(31.5) and lim['attitude_lag'][0] == pytest.approx(31.5)
    assert lim['thrust_max'][0] == pytest.approx(0.9 * crazyflie.thrust_max_n)
    assert lim['rotor_speed_max'][0] == pytest.approx(2250.0)
    assert lim['thrust_min'][0] == pytest.approx(0.1 * crazyflie.thrust_max_n)        # rotor_speed_min is 0
    assert lim['rotor_thrust_min'][0] == pytest.approx(0.1 * crazyflie.k_eta * 2500.0 ** 2)
    assert feasibility.margined_limits(crazyflie)['tilt'][0] == 35.0
    with pytest.raises(ValueError, match='margin = 1.0 must be a fraction'):
        feasibility.margined_limits(crazyflie, 1.0)


def test_mission_if_infeasible_is_validated():
    base = {'waypoints': [[0, 0, 1], [1, 0, 1]]}
    assert mission_from_dict(base).if_infeasible == 'refuse'
    assert mission_from_dict({**base, 'trajectory': {'if_infeasible': 'limits'}}).if_infeasible == 'limits'
    assert mission_from_dict({**base, 'trajectory': {'if_infeasible': 'fastest'}}).if_infeasible == 'fastest'
    with pytest.raises(ValueError, match="trajectory.if_infeasible = 'slow' must be one of refuse, fastest, limits"):
        mission_from_dict({**base, 'trajectory': {'if_infeasible': 'slow'}})
