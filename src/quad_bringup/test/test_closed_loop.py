"""The ROS-free flight loop used for tuning, the fast profile it produced, and fly's profile/timing options."""

import dataclasses

import numpy as np
import pytest

from quad_bringup.offline.closed_loop import LoopOptions, fly_offline, load_control_profile
from quad_bringup.running.flight import EXIT_REFUSED, fly
from quad_bringup.running.flight_options import (
    FlightOptions,
    MissionRefused,
    preflight_options,
    validate,
    with_profile_controller,
    write_flown_mission,
)
from quad_common.paths import resolve_config
from quad_common.yaml_io import load_yaml
from quad_control.parameters import SPECS, gains_from, profile_parameters
from quad_trajectory.mission import load_mission, plan_mission

FAST = resolve_config('config/control_fast.yaml')
MAZE = resolve_config('config/missions/maze.yaml')


def fast_profile():
    values = {spec.name: spec.default for spec in SPECS}
    values.update(profile_parameters(load_yaml(FAST)))
    return values['controller'], gains_from(values)


def test_seed_pd_at_half_a_metre_per_second_tracks_to_millimetres():
    m = fly_offline(MAZE, LoopOptions(speed_mps=0.5))
    assert m['completed'] and not m['collided'] and m['rmse_m'] < 0.005


def test_fast_profile_meets_the_2_mps_goal_where_the_seed_gains_do_not():
    controller, gains = fast_profile()
    fast = fly_offline(MAZE, LoopOptions(controller=controller, gains=gains, speed_mps=2.0))
    seed = fly_offline(MAZE, LoopOptions(speed_mps=2.0))
    assert fast['completed'] and fast['rmse_m'] < 0.02 and fast['time_over_s'] < 0.3
    assert seed['rmse_m'] > 0.05 and seed['time_over_s'] > 0.3
    windy = fly_offline(MAZE, LoopOptions(controller=controller, gains=gains, speed_mps=2.0,
                                          disturbances='drag_wind'))
    assert windy['completed'] and not windy['collided'] and windy['rmse_m'] < 0.05


def test_profile_names_the_controller_unless_fly_is_told_one():
    assert with_profile_controller(FlightOptions(MAZE, control_profile=FAST)).controller == 'se3'
    assert with_profile_controller(FlightOptions(MAZE, controller='pid', control_profile=FAST)).controller == 'pid'
    assert with_profile_controller(FlightOptions(MAZE)).controller == 'pd'


def test_flown_mission_carries_the_time_allocation_and_plans_the_same(tmp_path):
    figure8 = resolve_config('config/missions/figure8.yaml')
    options = FlightOptions(figure8, controller='se3', speed_mps=2.0, time_allocation='limits')
    mission = validate(options)
    flown = load_mission(write_flown_mission(options, mission, tmp_path / 'mission.yaml'))
    assert flown.options.time_allocation == 'limits' and flown.options.a_max_mps2 == 6.0
    planned = plan_mission(flown, speed_mps=2.0).trajectory
    expected = plan_mission(mission, speed_mps=2.0, time_allocation='limits').trajectory
    assert np.allclose(planned.durations_s, expected.durations_s)
    assert planned.max_acceleration() <= 6.0


def test_unknown_time_allocation_refused_naming_it():
    with pytest.raises(MissionRefused, match="--time-allocation 'fastests' refused: must be one of .*, fastest"):
        validate(FlightOptions(MAZE, controller='pd', time_allocation='fastests'))
    assert validate(FlightOptions(MAZE, controller='pd', time_allocation='fastest')).name == 'maze'


def test_72ms_motors_on_long_100_at_2_mps_do_not_spin():
    """The mixer's priority (yaw limited and last, roll/pitch kept): with the old one, where yaw took no share,
    this flight reached 24 rad/s of yaw rate and a 5.5 m RMSE."""
    controller, gains = load_control_profile(resolve_config('config/control_se3.yaml'))
    m = fly_offline(resolve_config('config/missions/long_100.yaml'),
                    LoopOptions(controller=controller, gains=gains, speed_mps=2.0, plant='slow_motors_72ms',
                                plan_overrides={'time_allocation': 'limits'}))
    assert m['completed'] and 'stopped' not in m
    assert m['max_yaw_rate_radps'] < 10.0 and m['rmse_m'] < 0.05


def test_se3_without_a_profile_flies_the_robust_one_and_pd_stays_the_seed():
    se3 = with_profile_controller(FlightOptions(MAZE, controller='se3'))
    assert se3.control_profile == resolve_config('config/control_se3.yaml')
    pd = with_profile_controller(FlightOptions(MAZE, controller='pd'))
    assert pd.control_profile is None
    controller, gains = load_control_profile(resolve_config('config/control.yaml'))
    assert controller == 'pd' and list(gains.kp) == [5.0, 5.0, 20.0] and list(gains.kd) == [5.0, 5.0, 10.0]
    assert gains.attitude_lead_s == 0.0 and gains.disturbance_time_constant_s == 0.0 and gains.thrust_scale == 1.0


def test_unknown_plant_member_refused_naming_it():
    with pytest.raises(MissionRefused, match="--plant 'wobbly'.*nominal"):
        validate(FlightOptions(MAZE, controller='se3', plant='wobbly'))


def test_node_parameters_carry_the_plant_to_sim_node():
    from quad_bringup.running.flight_options import node_parameters
    options = FlightOptions(MAZE, controller='se3', plant='autopilot_so3')
    validate(options)
    params = node_parameters(with_profile_controller(options))
    assert params['sim_node']['ros__parameters']['plant'] == 'autopilot_so3'
    assert params['position_controller']['ros__parameters']['attitude_lead_s'] == 0.12


# --- feasibility before flight ------------------------------------------------------------------

FIGURE8 = resolve_config('config/missions/figure8.yaml')


def test_fly_refuses_an_infeasible_plan_before_starting_anything(tmp_path):
    lines = []
    result = fly(FlightOptions(FIGURE8, controller='se3', speed_mps=2.0, out=tmp_path / 'run'), log=lines.append)
    assert result.exit_code == EXIT_REFUSED and 'not feasible on crazyflie' in result.reason
    assert '--fly-anyway' in result.reason and not (tmp_path / 'run').exists()   # no graph, no run directory
    fastest = plan_mission(load_mission(FIGURE8), speed_mps=2.0, time_allocation='fastest').trajectory.duration_s
    assert f'--time-allocation fastest flies it in {fastest:.2f} s' in result.reason   # the alternative and its time
    text = '\n'.join(lines)
    assert 'tilt: needs 48' in text and f'time_allocation fastest fits: {fastest:.2f} s planned' in text
    assert 'time_allocation limits fits' in text


def test_fly_anyway_and_the_missions_own_choice(tmp_path):
    mission = validate(FlightOptions(FIGURE8, controller='se3', speed_mps=2.0))
    anyway = FlightOptions(FIGURE8, controller='se3', speed_mps=2.0, fly_anyway=True)
    flown = preflight_options(anyway, mission, log=lambda line: None)
    assert flown.time_allocation is None and flown.rule.source == 'vehicle crazyflie'  # its completion: rule
    lines = []
    for choice in ('limits', 'fastest'):
        asks = dataclasses.replace(mission, if_infeasible=choice)
        chosen = preflight_options(FlightOptions(FIGURE8, controller='se3', speed_mps=2.0), asks, log=lines.append)
        assert chosen.time_allocation == choice and 'as the mission asks' in lines[-1]
    feasible = FlightOptions(MAZE, controller='pd', speed_mps=0.5)
    assert preflight_options(feasible, validate(feasible), log=lines.append).time_allocation is None
    assert lines[-1].startswith('feasible on crazyflie: tilt 2.1')


def test_a_profile_variant_sets_its_values_over_the_shipped_profile_and_leaves_it_alone():
    """profile_with: the benches' variants of a shipped profile (control_real as PX4 SIH flew it, drag learning off)."""
    from quad_common.paths import resolve_config
    from quad_common.yaml_io import load_yaml
    from quad_control.parameters import profile_parameters, profile_with
    shipped = load_yaml(resolve_config('config/control_real.yaml'))
    variant = profile_with(shipped, {'drag_learning_time_s': 0.0})
    assert profile_parameters(variant) == {**profile_parameters(shipped), 'drag_learning_time_s': 0.0}
    assert profile_parameters(shipped)['drag_learning_time_s'] == 20.0
