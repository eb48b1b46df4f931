"""A fleet flown offline (quad_bringup.offline.fleet_loop) and `quadflight plan FLEET.yaml`."""

import json

import numpy as np
import pytest

from quad_bringup import cli
from quad_bringup.offline.fleet_loop import fly_fleet
from quad_common.paths import resolve_config
from quad_common.yaml_io import load_yaml
from quad_sim.vehicle_contact import VEHICLE_COLLISION, closest_approach, contact_fraction
from quad_trajectory.fleet import fleet_from_dict

FORMATION = str(resolve_config('config/missions/fleets/formation4.yaml'))
CROSSING = str(resolve_config('config/missions/fleets/crossing2.yaml'))


def crossing(**separation_options):
    data = load_yaml(CROSSING)
    data['separation'].update(separation_options)
    return fleet_from_dict(data, CROSSING)


@pytest.fixture(scope='module')
def formation():
    return fly_fleet(FORMATION)


def test_four_vehicle_formation_completes_with_small_tracking_error(formation):
    assert formation.names == ['cf1', 'cf2', 'cf3', 'cf4']
    for name, m in formation.metrics.items():
        assert m['completed'], name
        assert m['rmse_m'] < 0.012 and m['max_error_m'] < 0.02, (name, m['rmse_m'], m['max_error_m'])
        assert m['time_actual_s'] < m['time_planned_s'] + 0.5
        assert m['vehicle_collisions'] == 0
    assert formation.collisions == []
    # cf4 flies the pid controller its entry names (8.8 mm), the others the default pd (7.5 mm)
    assert formation.metrics['cf4']['rmse_m'] > formation.metrics['cf1']['rmse_m'] + 5e-4
    distance, _ = formation.closest()
    assert 0.78 < distance < 0.81             # the planned 0.8 m square, kept within 2 cm while flying
    assert formation.sim_s == pytest.approx(max(m['time_actual_s'] for m in formation.metrics.values()), abs=0.02)


def test_one_controller_dies_its_failsafe_lands_it_and_the_others_complete():
    run = fly_fleet(FORMATION, controller_stops={'cf1': 2.0})
    kinds = [(e.kind, e.time_s) for name, e in run.events
             if name == 'cf1' and e.kind in ('failsafe', 'touchdown', 'disarmed')]
    assert [k for k, _ in kinds] == ['failsafe', 'touchdown', 'disarmed']
    assert kinds[0][1] == pytest.approx(1.99 + 0.5, abs=0.002)   # setpoint_timeout_s after the last setpoint
    assert all(name == 'cf1' for name, e in run.events)         # the others never noticed
    landed = run.positions['cf1'][-1]
    assert landed[2] == pytest.approx(0.0, abs=1e-6)
    assert not run.metrics['cf1']['completed']
    assert all(run.metrics[n]['completed'] for n in ('cf2', 'cf3', 'cf4'))
    assert run.collisions == []


def test_a_mixed_fleet_flies_each_vehicle_file_radius_and_profile():
    data = load_yaml(FORMATION)
    data['vehicles'][1].update(vehicle='../../vehicles/px4_quad.yaml', robot_radius_m=0.3)
    data['vehicles'][2].update(profile='../../control_fast.yaml')
    fleet = fleet_from_dict(data, FORMATION)
    assert fleet.vehicles[1].mission.vehicle.name == 'px4_quad'
    run = fly_fleet(fleet)
    assert run.plan.report.required_m[0, 1] == pytest.approx(0.5)     # 0.1 + 0.3 + margin 0.1
    assert run.plan.report.required_m[0, 2] == pytest.approx(0.3)
    assert run.controllers == {'cf1': 'pd', 'cf2': 'pd', 'cf3': 'se3', 'cf4': 'pid'}
    assert all(m['completed'] for m in run.metrics.values())
    assert run.metrics['cf3']['rmse_m'] < 0.5 * run.metrics['cf1']['rmse_m']   # the fast profile tracks closer


def test_crossing_is_refused_before_flight():
    with pytest.raises(ValueError, match='cf1 and cf2 come 0.000 m apart at t = 4.00 s'):
        fly_fleet(crossing())


def test_crossing_deconflicted_by_a_delay_flies_without_collision():
    run = fly_fleet(crossing(deconflict='delays'))
    assert run.plan.delays_s == [0.0, 0.5]
    assert run.collisions == []
    assert all(m['completed'] and not m['collided'] for m in run.metrics.values())
    assert run.closest()[0] > 0.35            # planned 0.385 m apart at the crossing


def test_crossing_flown_anyway_collides_and_both_vehicles_report_it():
    run = fly_fleet(crossing(), refuse_conflicts=False)
    assert len(run.collisions) == 1
    t, a, b, distance = run.collisions[0]
    # 0.2 m apart (two radii) when each is 0.2 / sqrt(2) = 0.141 m from the origin, ~0.13 s before both reach it
    assert (a, b) == ('cf1', 'cf2') and t == pytest.approx(3.866, abs=0.005)
    assert distance < 0.2
    kinds = [(name, e.kind, e.detail.get('other')) for name, e in run.events if e.kind == VEHICLE_COLLISION]
    assert kinds == [('cf1', VEHICLE_COLLISION, 'cf2'), ('cf2', VEHICLE_COLLISION, 'cf1')]
    assert all(m['collided'] and not m['completed'] for m in run.metrics.values())


def test_a_graze_between_ticks_is_found_by_the_linear_closest_approach():
    # the two pass 0.05 m apart half way between the ticks; both tick-time distances are 1.0 m or more
    p0 = np.array([[-0.5, 0.0, 1.0], [0.5, 0.05, 1.0]])
    p1 = np.array([[0.5, 0.0, 1.0], [-0.5, 0.05, 1.0]])
    d = closest_approach(p0, p1, np.array([0]), np.array([1]))
    assert d[0] == pytest.approx(0.05)
    # contact (0.2 m) where the gap x(s) = 1 - 2 s has sqrt(x^2 + 0.05^2) = 0.2: s = (1 - sqrt(0.0375)) / 2
    assert contact_fraction(p0, p1, 0, 1, 0.2) == pytest.approx((1 - np.sqrt(0.2 ** 2 - 0.05 ** 2)) / 2)
    assert contact_fraction(p0, p0, 0, 1, 2.0) == 0.0           # already touching at the tick


def test_plan_command_prints_each_vehicle_and_the_minimum_separation(capsys, tmp_path):
    out = tmp_path / 'fleet.json'
    assert cli.main(['plan', FORMATION, '--out', str(out)]) == 0
    text = capsys.readouterr().out
    assert all(f'\ncf{k} ' in text for k in range(1, 5))
    assert 'minimum separation: 0.800 m' in text and 'required 0.300 m' in text
    written = json.loads(out.read_text())
    assert set(written['vehicles']) == {'cf1', 'cf2', 'cf3', 'cf4'}
    assert written['separation']['minimum_m'] == pytest.approx(0.8)
    assert written['vehicles']['cf2']['waypoints'][0] == pytest.approx([0.4, -0.4, 1.0])


def test_plan_command_refuses_a_conflict_with_exit_2_and_one_line(capsys):
    assert cli.main(['plan', CROSSING]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert 'separation conflict: cf1 and cf2 come 0.000 m apart at t = 4.00 s' in err[0]


def test_plan_command_on_a_single_vehicle_mission_is_unchanged(capsys):
    assert cli.main(['plan', str(resolve_config('config/missions/maze.yaml'))]) == 0
    assert 'time planned (s)' in capsys.readouterr().out


def test_fleet_command_flies_the_formation_and_writes_its_results(capsys, tmp_path):
    assert cli.main(['fleet', FORMATION, '--out', str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert 'flown minimum separation: 0.79' in out and 'COLLISION' not in out
    written = json.loads((tmp_path / 'fleet.json').read_text())
    assert all(m['completed'] for m in written['metrics'].values()) and written['collisions'] == []
    assert (tmp_path / 'fleet.png').stat().st_size > 10_000


def test_fleet_command_refuses_the_crossing_and_flown_anyway_fails_on_the_collision(capsys):
    assert cli.main(['fleet', CROSSING]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'separation conflict: cf1 and cf2' in err[0]
    assert cli.main(['fleet', CROSSING, '--fly-anyway']) == 1
    assert 'COLLISION: cf1 and cf2 at t = 3.87 s' in capsys.readouterr().out
