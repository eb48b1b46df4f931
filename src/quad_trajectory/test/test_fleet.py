"""Fleet missions (quad_trajectory.fleet) and the separation check before flight (quad_trajectory.separation)."""

import numpy as np
import pytest

from quad_common.paths import resolve_config
from quad_common.yaml_io import load_yaml
from quad_trajectory import separation
from quad_trajectory.fleet import fleet_from_dict, is_fleet_file, load_fleet, plan_fleet
from quad_trajectory.mission import load_mission

FORMATION = str(resolve_config('config/missions/fleets/formation4.yaml'))
CROSSING = str(resolve_config('config/missions/fleets/crossing2.yaml'))


def crossing(**separation_options):
    data = load_yaml(CROSSING)
    data['separation'].update(separation_options)
    return fleet_from_dict(data, CROSSING)


class Line:
    """p(t) = start + velocity t for t in [0, duration] (the interface separation.check uses)."""

    def __init__(self, start, velocity, duration_s):
        self.start, self.velocity, self.duration_s = np.array(start, float), np.array(velocity, float), duration_s

    def evaluate(self, t_s, order=0):
        t = np.clip(np.asarray(t_s, dtype=float), 0.0, self.duration_s)[..., None]
        return np.concatenate([self.start + self.velocity * t, np.zeros(t.shape)], axis=-1)

    def max_speed(self):
        return float(np.linalg.norm(self.velocity))


def test_formation_offsets_the_shared_path_and_keeps_the_square():
    fleet = load_fleet(FORMATION)
    assert fleet.names == ['cf1', 'cf2', 'cf3', 'cf4']
    shared = np.array(load_yaml(FORMATION)['waypoints'])
    np.testing.assert_allclose(fleet.vehicles[1].mission.waypoints, shared + [0.4, -0.4, 0.0])
    np.testing.assert_allclose(fleet.vehicles[1].mission.initial_position, [0.4, -0.4, 1.0])
    assert fleet.vehicles[3].controller == 'pid'
    result = plan_fleet(fleet)
    assert result.refusal() is None
    closest = result.report.closest
    assert closest[2] == pytest.approx(0.8, abs=1e-6)         # the square's side, all the way
    assert result.report.required_m[0, 1] == pytest.approx(0.3)   # 0.1 + 0.1 + margin 0.1
    assert result.report.distance_m[0, 3] == pytest.approx(0.8 * np.sqrt(2), abs=1e-6)


def test_start_is_prepended_and_a_vehicle_trajectory_key_overrides_the_fleets():
    data = load_yaml(FORMATION)
    data['vehicles'][0].update(start=[-1.0, -1.0, 1.0], trajectory={'speed': 0.25})
    fleet = fleet_from_dict(data, FORMATION)
    v = fleet.vehicles[0]
    np.testing.assert_allclose(v.mission.initial_position, [-1.0, -1.0, 1.0])
    assert len(v.mission.waypoints) == 4
    assert v.mission.options.speed_mps == 0.25 and v.mission.options.method == 'minsnap'
    assert fleet.vehicles[1].mission.options.speed_mps == 0.5
    data['vehicles'][0]['yaw'] = [0.1, 0.2, 0.3]                 # one per shared waypoint: the start gets the first's
    assert fleet_from_dict(data, FORMATION).vehicles[0].mission.yaw == [0.1, 0.1, 0.2, 0.3]


def test_crossing_paths_are_refused_naming_the_pair_the_time_and_the_distance():
    result = plan_fleet(crossing())
    conflict = result.report.conflicts[0]
    assert (conflict.a, conflict.b) == ('cf1', 'cf2')
    assert conflict.time_s == pytest.approx(4.0, abs=0.01)     # both reach the origin half way through 8 s
    assert conflict.distance_m < 0.005
    line = result.refusal()
    assert 'cf1 and cf2 come 0.000 m apart at t = 4.00 s' in line and 'minimum separation 0.300 m' in line


def test_min_separation_field_sets_the_threshold():
    data = load_yaml(FORMATION)
    data['separation'] = {'min_m': 0.85}
    result = plan_fleet(fleet_from_dict(data, FORMATION))
    assert len(result.report.conflicts) == 4                    # the four sides (0.8 m), not the diagonals (1.13 m)
    assert {(c.a, c.b) for c in result.report.conflicts} == {('cf1', 'cf2'), ('cf1', 'cf3'), ('cf2', 'cf4'),
                                                              ('cf3', 'cf4')}


def test_sample_step_catches_a_fast_graze_between_coarse_samples():
    # 10 m/s each, at right angles: closest 0.29 m at t = 0.55 s, midway between 0.1 s samples
    a = Line([-5.5, 0.0, 1.0], [10.0, 0.0, 0.0], 1.2)
    b = Line([0.0, -5.5, 1.29], [0.0, 10.0, 0.0], 1.2)
    assert separation.step_for([a.max_speed(), b.max_speed()]) == pytest.approx(0.0005)   # 2 x 5 mm / 20 m/s
    req = separation.required_matrix([0.1, 0.1], 0.1)
    report = separation.check([a, b], ['a', 'b'], [0.0, 0.0], req)
    assert len(report.conflicts) == 1
    assert report.conflicts[0].distance_m == pytest.approx(0.29, abs=1e-4)
    assert report.conflicts[0].time_s == pytest.approx(0.55, abs=1e-4)


def test_delays_deconflict_the_crossing_and_say_so():
    result = plan_fleet(crossing(deconflict='delays'))
    assert result.delays_s == [0.0, 0.5]
    assert result.changes and result.changes[0].startswith('cf2: starts 0.5 s later')
    assert not result.before.ok and result.report.ok
    assert result.report.closest[2] >= 0.3


def test_the_first_clear_delay_is_taken():
    result = plan_fleet(crossing(deconflict='delays', delay_step_s=0.1))
    delay = result.delays_s[1]
    assert 0.1 < delay < 0.5 and result.report.ok
    assert result.report.closest[2] >= 0.3
    one_step_less = plan_fleet(crossing(deconflict='none')).fleet
    one_step_less.vehicles[1].start_delay_s = delay - 0.1
    assert not plan_fleet(one_step_less).report.ok          # the step before it still conflicts


def test_altitude_layers_deconflict_the_crossing():
    result = plan_fleet(crossing(deconflict='altitude'))
    assert result.delays_s == [0.0, 0.0]
    assert result.changes[0].startswith('cf2: flies +0.5 m higher')
    assert result.fleet.vehicles[1].mission.waypoints[:, 2] == pytest.approx([1.5, 1.5])
    assert result.plans[1].trajectory.evaluate(4.0)[2] == pytest.approx(1.5)
    assert result.report.closest[2] == pytest.approx(0.5, abs=1e-3)


def test_deconfliction_without_a_clear_candidate_names_the_vehicle():
    with pytest.raises(ValueError, match='no clear candidate for cf2: cf1 and cf2 come 0.000 m apart'):
        plan_fleet(crossing(deconflict='delays', max_delay_s=0.4))


@pytest.mark.parametrize('change, message', [
    (lambda d: d['vehicles'][1]['waypoints'].__setitem__(1, [2.0, 0.0, float('nan')]),
     r"vehicles\[1\] \(cf2\): waypoints\[1\] = \[2.0, 0.0, nan\] must be finite"),
    (lambda d: d['vehicles'][1].update(trajectory={'method': 'fast'}),
     r"vehicles\[1\] \(cf2\): method = 'fast' must be one of"),
    (lambda d: d['vehicles'][1].update(name='cf1'), r"vehicles\[1\] \(cf1\): name = 'cf1' is already vehicles\[0\]"),
    (lambda d: d['vehicles'][0].update(name='1a'), r"vehicles\[0\] \(1a\): name = '1a' must be a letter"),
    (lambda d: d['vehicles'][0].update(offset=[1, 2]), r"vehicles\[0\] \(cf1\): waypoints and offset = \[1, 2\]"),
    (lambda d: d['vehicles'][0].update(start=[0, 0]), r"vehicles\[0\] \(cf1\): start = \[0, 0\] must be \[x, y, z\]"),
    (lambda d: d['vehicles'][0].update(colour='red'), r"vehicles\[0\] \(cf1\): colour = 'red' is not a known key"),
    (lambda d: d['vehicles'][0].update(vehicle='nope.yaml'), r"vehicles\[0\] \(cf1\): .*nope.yaml"),
    (lambda d: d['vehicles'][0].update(robot_radius_m=-1), r"vehicles\[0\] \(cf1\): robot_radius_m = -1"),
    (lambda d: d['separation'].update(deconflict='later'), r"separation.deconflict = 'later' must be one of"),
    (lambda d: d['separation'].update(delay_step_s=0), r"separation.delay_step_s = 0 must be > 0"),
    (lambda d: d.update(vehicles=[]), r"vehicles = \[\] must be a list of at least one vehicle"),
])
def test_errors_name_the_vehicle_the_field_and_the_value(change, message):
    data = load_yaml(CROSSING)
    change(data)
    with pytest.raises(ValueError, match=message):
        fleet_from_dict(data, CROSSING)


def test_single_vehicle_missions_are_not_fleets_and_load_unchanged():
    maze = resolve_config('config/missions/maze.yaml')
    assert not is_fleet_file(maze) and is_fleet_file(FORMATION)
    assert load_mission(maze).waypoints.shape[1] == 3
    with pytest.raises(ValueError, match='a fleet mission'):   # never one vehicle of a fleet by mistake
        load_mission(FORMATION)


# --- real vehicles: autopilot, fcu_url, system_id (the fleet bridge graph, docs/bridge.md) -----------------------

SITL3 = str(resolve_config('config/missions/fleets/sitl3.yaml'))


def test_real_vehicle_keys_are_read():
    fleet = load_fleet(SITL3)
    assert [(v.autopilot, v.fcu_url, v.system_id) for v in fleet.vehicles] == [
        ('px4', 'udpin:0.0.0.0:14540', 1), ('px4', 'udpin:0.0.0.0:14541', 2), ('ardupilot', 'tcp:127.0.0.1:5770', 3)]
    assert plan_fleet(fleet).report.ok
    assert load_fleet(FORMATION).vehicles[0].system_id is None    # optional: a simulated fleet has none


def _sitl3(change):
    data = load_yaml(SITL3)
    change(data)
    return fleet_from_dict(data, SITL3)


@pytest.mark.parametrize('change, message', [
    (lambda d: d['vehicles'][1].update(system_id=1),
     r"vehicles\[1\] \(px4_2\): system_id = 1 is already vehicles\[0\] \(px4_1\)'s"),
    (lambda d: d['vehicles'][1].update(fcu_url='udpin:127.0.0.1:14540'),
     r"vehicles\[1\] \(px4_2\): fcu_url = 'udpin:127.0.0.1:14540' listens on port 14540 as vehicles\[0\] \(px4_1\)'s"),
    (lambda d: d['vehicles'][2].update(fcu_url='udpout:10.0.0.2:14540'), None),   # another host's port: fine
    (lambda d: d['vehicles'][0].update(fcu_url='tcp:127.0.0.1:5770'),
     r"vehicles\[2\] \(apm_3\): fcu_url = 'tcp:127.0.0.1:5770' talks to 127.0.0.1:5770 as vehicles\[0\]"),
    (lambda d: d['vehicles'][0].update(system_id=0), r"vehicles\[0\] \(px4_1\): system_id = 0 must be a whole number"),
    (lambda d: d['vehicles'][0].update(system_id=256), r"system_id = 256 must be a whole number 1..255"),
    (lambda d: d['vehicles'][0].update(system_id='1'), r"system_id = '1' must be a whole number"),
    (lambda d: d['vehicles'][0].update(system_id=True), r"system_id = True must be a whole number"),
    (lambda d: d['vehicles'][0].update(autopilot='betaflight'),
     r"vehicles\[0\] \(px4_1\): autopilot = 'betaflight' must be one of px4, ardupilot"),
    (lambda d: d.update(autopilot='inav'), r"sitl3.yaml: autopilot = 'inav' must be one of px4, ardupilot"),
    (lambda d: d['vehicles'][0].update(fcu_url='udpin:14540'), r"vehicles\[0\] \(px4_1\): fcu_url = 'udpin:14540' "
                                                                r"must be udpin:HOST:PORT"),
    (lambda d: d['vehicles'][0].update(fcu_url=14540), r"fcu_url = 14540 must be udpin:HOST:PORT"),
    (lambda d: d['vehicles'][0].update(system_idd=1), r"system_idd = 1 is not a known key"),
])
def test_real_vehicle_errors_name_the_vehicle_the_field_and_the_value(change, message):
    if message is None:
        _sitl3(change)
        return
    with pytest.raises(ValueError, match=message):
        _sitl3(change)


def test_the_fleets_autopilot_is_every_vehicles_default():
    def change(d):
        d['autopilot'] = 'ardupilot'
        del d['vehicles'][0]['autopilot']
    fleet = _sitl3(change)
    assert [v.autopilot for v in fleet.vehicles] == ['ardupilot', 'px4', 'ardupilot']


def test_vehicle_mission_is_the_vehicles_own_or_deconflicted():
    from quad_trajectory.fleet import vehicle_mission
    mission, delay = vehicle_mission(crossing(deconflict='none'), 'cf2')
    assert delay == 0.0 and mission.waypoints[0].tolist() == [-2.0, 0.0, 1.0]
    assert vehicle_mission(crossing(deconflict='delays'), 'cf2')[1] == 0.5
    mission, delay = vehicle_mission(crossing(deconflict='altitude'), 'cf2')
    assert delay == 0.0 and mission.waypoints[:, 2] == pytest.approx([1.5, 1.5])
    with pytest.raises(ValueError, match=r"fleet_vehicle = 'cf9' is not one of its vehicles \(cf1, cf2\)"):
        vehicle_mission(crossing(), 'cf9')
