"""Bad input refused before anything starts, in one line naming the field and the value, exit 2, nothing left
behind and no input modified."""

import json
import shutil
from pathlib import Path

import pytest

from quad_bringup import cli
from quad_bringup.checks.profiles import check_control_profile
from quad_common.paths import REPO_ROOT
from quad_common.yaml_io import load_yaml

MISSION = 'name: tiny\nwaypoints:\n  - [0.0, 0.0, 1.0]\n  - [1.0, 0.0, 1.0]\ntrajectory:\n  speed: 0.5\n'


def _main(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.fixture
def mission(tmp_path):
    path = tmp_path / 'm.yaml'
    path.write_text(MISSION)
    return path


def test_plan_out_onto_its_mission_is_refused_and_the_mission_kept(capsys, mission):
    code, _, err = _main(capsys, 'plan', mission, '--out', mission)
    assert code == 2 and 'it is the mission, an input' in err
    assert mission.read_text() == MISSION
    code, _, err = _main(capsys, 'plan', mission, '--out', mission.with_suffix('.json'), '--csv', '10')
    assert code == 0 and json.loads(mission.with_suffix('.json').read_text())['segments']
    csv_onto_mission = mission.with_name('m.csv')   # --csv writes next to --out: m.csv
    shutil.copy(mission, csv_onto_mission)
    code, _, err = _main(capsys, 'plan', csv_onto_mission, '--out', mission.with_name('m.json'), '--csv', '10')
    assert code == 2 and '--csv (next to --out)' in err and csv_onto_mission.read_text() == MISSION


def test_plan_csv_rows_are_bounded_before_anything_is_written(capsys, tmp_path):
    far = tmp_path / 'far.yaml'
    far.write_text(MISSION.replace('[1.0, 0.0, 1.0]', '[1.0e9, 0.0, 1.0]'))
    out = tmp_path / 'far.json'
    code, _, err = _main(capsys, 'plan', far, '--out', out, '--csv', '1')
    assert code == 2 and 'rows, above 1,000,000' in err and 'Traceback' not in err
    assert not out.exists() and not out.with_suffix('.csv').exists()
    code, _, err = _main(capsys, 'plan', far, '--out', out, '--csv', '1e12')
    assert code == 2 and '--csv 1e+12 refused: must be > 0 and <= 1e+06 Hz' in err


def test_plan_takes_flys_limits_and_refuses_a_directory(capsys, mission, tmp_path):
    code, _, err = _main(capsys, 'plan', mission, '--speed', '1e12')
    assert code == 2 and '--speed 1e+12 refused: must be > 0 and <= 100 m/s' in err
    code, _, err = _main(capsys, 'plan', tmp_path)
    assert code == 2 and 'a directory, not a mission file' in err and len(err.strip().splitlines()) == 1


def test_ctrl_c_during_plan_is_one_line_and_exit_130(capsys, mission, monkeypatch):
    import quad_trajectory.mission as mission_module

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt
    monkeypatch.setattr(mission_module, 'plan_mission', interrupted)
    code, _, err = _main(capsys, 'plan', mission)
    assert code == 130 and err.strip() == 'quadflight plan: interrupted'


def test_identify_never_replaces_a_file_it_did_not_write(capsys, tmp_path):
    precious = tmp_path / 'notes.yaml'
    precious.write_text('mine: true\n')
    code, _, err = _main(capsys, 'identify', tmp_path / 'bag', '--out', precious)
    assert code == 2 and 'not written by quadflight identify' in err and precious.read_text() == 'mine: true\n'
    code, _, err = _main(capsys, 'identify', tmp_path / 'bag', '--latency-s', '-1')
    assert code == 2 and '--latency-s -1 refused' in err


def test_report_refusals_leave_no_directory_and_share_flys_limits(capsys, tmp_path):
    not_a_bag = tmp_path / 'not_a_bag'
    not_a_bag.mkdir()
    (not_a_bag / 'readme.txt').write_text('hello')
    out = tmp_path / 'report_out'
    code, _, err = _main(capsys, 'report', not_a_bag, '--out', out)
    assert code == 2 and 'Traceback' not in err and not out.exists()
    code, _, err = _main(capsys, 'report', not_a_bag, '--position-tolerance', '1e9')
    assert code == 2 and '--position-tolerance 1e+09 refused: must be > 0 and <= 100 m' in err
    code, _, err = _main(capsys, 'report', not_a_bag, '--settle', '-1')
    assert code == 2 and '--settle -1 refused: must be >= 0' in err


PROFILES = {  # file content -> what the refusal names
    'position_controller:\n  ros__parameters:\n    kp_xx: 50.0\n': "kp_xx = 50.0 refused: not a parameter of "
                                                                   "position_controller (did you mean 'kp_x'?)",
    'position_controller:\n  ros__parameters:\n    kp_x: -5.0\n': 'kp_x = -5.0 refused: must be >= 0.0',
    'position_control:\n  ros__parameters:\n    kp_x: 5.0\n': 'no position_controller: key (found position_control)',
    'name: q\nmass_kg: 1.5\narm_length_m: 0.2\n': 'a vehicle file (mass_kg, arm_length_m), not a control profile',
}


@pytest.mark.parametrize('content', list(PROFILES))
def test_fly_checks_the_control_profile_before_anything_starts(capsys, tmp_path, content):
    profile = tmp_path / 'profile.yaml'
    profile.write_text(content)
    run_dir = tmp_path / 'run'
    code, _, err = _main(capsys, 'fly', REPO_ROOT / 'config/missions/maze.yaml', '--control-profile', profile,
                         '--out', run_dir)
    assert code == 2 and PROFILES[content] in err and not run_dir.exists()


def test_fly_checks_the_disturbances_before_anything_starts(capsys, tmp_path):
    code, _, err = _main(capsys, 'fly', REPO_ROOT / 'config/missions/maze.yaml', '--disturbances', 'hurricane',
                         '--out', tmp_path / 'run')
    assert code == 2 and "--disturbances: disturbances = 'hurricane': no such profile" in err
    assert not (tmp_path / 'run').exists()


@pytest.mark.parametrize('profile', sorted(p.name for p in (REPO_ROOT / 'config').glob('control*.yaml')))
def test_every_shipped_control_profile_passes_the_check(profile):
    path = Path(REPO_ROOT / 'config' / profile)
    assert check_control_profile(path) == load_yaml(path)['position_controller']['ros__parameters']


def test_typos_of_known_keys_are_refused_naming_the_key(capsys, tmp_path):
    typo = tmp_path / 'typo.yaml'
    typo.write_text(MISSION + 'robot_raduis_m: 0.2\n')
    code, _, err = _main(capsys, 'plan', typo)
    assert code == 2 and "robot_raduis_m = 0.2 is not a known key (did you mean 'robot_radius_m'?)" in err
    vehicle = tmp_path / 'v.yaml'
    vehicle.write_text((REPO_ROOT / 'config/vehicles/px4_quad.yaml').read_text() + 'mass_kgg: 2.0\n')
    typo.write_text(MISSION + f'vehicle: {vehicle}\n')
    code, _, err = _main(capsys, 'plan', typo)
    assert code == 2 and "mass_kgg = 2.0 is not a known key (did you mean 'mass_kg'?)" in err


def test_a_number_yaml_reads_as_text_is_named_with_how_to_write_it(capsys, tmp_path):
    text = tmp_path / 'text.yaml'
    text.write_text(MISSION.replace('speed: 0.5', 'speed: 1e9'))
    code, _, err = _main(capsys, 'plan', text)
    assert code == 2 and "trajectory.speed = '1e9' is text to YAML, not a number" in err and '1.0e+9' in err


SWEEP = {'missions': ['config/missions/stop_every_waypoint.yaml'], 'controllers': ['pd'], 'seeds': 1}


@pytest.mark.parametrize('argv, says', [
    (['--workers', '-1'], '--workers -1 refused: must be an integer >= 1'),
    (['--scheduler', 'notaurl'], "--scheduler 'notaurl' refused"),
])
def test_sweep_and_tune_refusals_are_one_line_and_leave_nothing(capsys, tmp_path, argv, says):
    spec = tmp_path / 'spec.yaml'
    spec.write_text(json.dumps(SWEEP))
    out = tmp_path / 'out'
    code, _, err = _main(capsys, 'sweep', spec, '--out', out, *argv)
    assert code == 2 and says in err and 'Traceback' not in err and not out.exists()


def test_sweep_out_must_be_a_writable_directory(capsys, tmp_path):
    spec = tmp_path / 'spec.yaml'
    spec.write_text(json.dumps(SWEEP))
    code, _, err = _main(capsys, 'sweep', spec, '--out', spec)
    assert code == 2 and 'a file, not a directory' in err and json.loads(spec.read_text()) == SWEEP
    code, _, err = _main(capsys, 'sweep', spec, '--out', '/proc/quadflight_out')
    assert code == 2 and 'cannot create or write it' in err


def test_tune_checks_its_optimizer_and_leaves_no_spec_behind(capsys, tmp_path):
    spec = tmp_path / 'tune.yaml'
    spec.write_text(json.dumps({'controller': 'pd', 'parameters': {'kp_xy': [1.0, 40.0]},
                                'missions': ['config/missions/stop_every_waypoint.yaml'],
                                'optimizer': {'maxiter': -1}}))
    out = tmp_path / 'out'
    code, _, err = _main(capsys, 'tune', spec, '--out', out, '--workers', '1')
    assert code == 2 and 'optimizer.maxiter = -1 refused: must be an integer >= 1' in err and not out.exists()


def _foreign_bag(path):
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore
    ts = get_typestore(Stores.ROS2_JAZZY)
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection('/chatter', 'std_msgs/msg/String', typestore=ts)
        for i in range(5):
            writer.write(conn, i * 10 ** 8, ts.serialize_cdr(ts.types['std_msgs/msg/String'](data='x'),
                                                             'std_msgs/msg/String'))
    return path


def test_a_bag_of_foreign_topics_and_a_binary_mission_are_one_line_naming_the_file(capsys, tmp_path):
    bag = _foreign_bag(tmp_path / 'foreign')
    for argv in (['report', bag, '--out', tmp_path / 'rep'], ['identify', bag, '--out', tmp_path / 'p.yaml']):
        code, _, err = _main(capsys, *argv)
        assert code == 2 and str(bag) in err and 'in it' in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / 'rep').exists() and not (tmp_path / 'p.yaml').exists()
    binary = tmp_path / 'binary.yaml'
    binary.write_bytes(bytes(range(256)) * 4)
    code, _, err = _main(capsys, 'plan', binary)
    assert code == 2 and f'{binary}: not a text (UTF-8) file' in err


def test_tune_out_a_file_and_a_closed_scheduler_leave_nothing(capsys, tmp_path):
    spec = tmp_path / 'tune.yaml'
    spec.write_text(json.dumps({'controller': 'pd', 'parameters': {'kp_xy': [1.0, 40.0]},
                                'missions': ['config/missions/stop_every_waypoint.yaml']}))
    code, _, err = _main(capsys, 'tune', spec, '--out', spec)
    assert code == 2 and 'a file, not a directory' in err
    sweep_spec = tmp_path / 'sweep.yaml'
    sweep_spec.write_text(json.dumps(SWEEP))
    out = tmp_path / 'out'
    code, _, err = _main(capsys, 'sweep', sweep_spec, '--out', out, '--scheduler', 'tcp://127.0.0.1:9')
    assert code == 2 and 'cannot connect' in err and not out.exists()   # no empty runs.csv / runs.jsonl


def test_fly_on_a_run_directory_another_fly_holds_is_refused_naming_it(capsys, tmp_path):
    import os

    from quad_bringup.running.flight_options import claim_run_dir
    run_dir = tmp_path / 'run'
    run_dir.mkdir()
    lock = claim_run_dir(run_dir)   # what a fly in flight holds (flock: one open file description per claim)
    try:
        code, _, err = _main(capsys, 'fly', REPO_ROOT / 'config/missions/maze.yaml', '--out', run_dir)
    finally:
        os.close(lock)
    assert code == 2 and f'--out {run_dir}: another command writes there now (fly pid {os.getpid()})' in err
    assert len(err.strip().splitlines()) == 1 and sorted(p.name for p in run_dir.iterdir()) == ['.quadflight.lock']


@pytest.mark.parametrize('mine', ['report.md', 'logs', 'metrics.json'])
def test_fly_never_overwrites_what_its_out_holds(capsys, tmp_path, mine):
    run_dir = tmp_path / 'notes'
    run_dir.mkdir()
    (run_dir / mine).write_text('my own\n')
    code, _, err = _main(capsys, 'fly', REPO_ROOT / 'config/missions/maze.yaml', '--out', run_dir)
    assert code == 2 and f'--out {run_dir}: already holds {mine}' in err and 'overwrites nothing' in err
    assert [p.name for p in run_dir.iterdir()] == [mine] and (run_dir / mine).read_text() == 'my own\n'


def test_a_disturbance_a_sweep_spec_defines_is_checked_in_the_file_it_wrote(tmp_path):
    """sweep --graph and tune's verification fly spec-defined profiles from their own disturbances_file."""
    from quad_bringup.checks.inputs import check_inputs
    from quad_bringup.running.flight_options import FlightOptions

    profiles = tmp_path / 'disturbances.yaml'
    profiles.write_text('wind-1.0: {wind_mps: [1.0, 0.0, 0.0]}\n')   # as runs.py writes it: base resolved
    mission = REPO_ROOT / 'config/missions/window.yaml'
    check_inputs(FlightOptions(mission, disturbances='wind-1.0', sim_parameters={'disturbances_file': str(profiles)}))
    with pytest.raises(ValueError, match="'wind-1.0': no such profile in .*config/disturbances.yaml"):
        check_inputs(FlightOptions(mission, disturbances='wind-1.0'))


def test_tune_fails_when_its_verification_could_not_fly(capsys, tmp_path, monkeypatch):
    import quad_bringup.experiments.tune as tune

    def tuned(spec, out, **kwargs):
        out.mkdir()
        (out / 'verify.md').write_text('| mission |\n')
        return {'aggregate': 'p95', 'cost_before_m': 0.1, 'cost_after_m': 0.05, 'evaluations': 3, 'runs': 6,
                'best_gains': {}, 'base_gains': {},
                'verify': [{'mission': 'window', 'graph_completed': True, 'graph_failure': None},
                           {'mission': 'maze', 'graph_completed': False,
                            'graph_failure': "--disturbances: disturbances = 'wind-1.0': no such profile\nmore"}]}
    monkeypatch.setattr(tune, 'run_tune', tuned)
    code, out, err = _main(capsys, 'tune', tmp_path / 'spec.yaml', '--out', tmp_path / 'out')
    assert code == 1 and 'profile:' in out
    assert err.strip() == ("tune: the verification through the ROS graph failed on 1 of 2 missions (maze: "
                           "--disturbances: disturbances = 'wind-1.0': no such profile); profile.yaml is written, "
                           "unverified")


def test_replay_without_a_model_says_identify_writes_it(capsys, tmp_path):
    bag = tmp_path / 'bag'
    bag.mkdir()
    code, _, err = _main(capsys, 'replay', bag)
    assert code == 2 and err.strip() == (f'quadflight replay: {bag}: no vehicle model beside it (bag_vehicle.yaml): '
                                         f'quadflight identify {bag} writes it, or give --vehicle MODEL.yaml')


def test_inputs_are_bounded_and_errors_name_the_value_not_the_file(capsys, tmp_path):
    bomb = tmp_path / 'bomb.yaml'   # nine anchors of nine aliases: 9^9 values once expanded
    lines = ['name: b', 'a0: &a0 [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0]']
    lines += [f'a{i}: &a{i} [{", ".join([f"*a{i - 1}"] * 9)}]' for i in range(1, 10)]
    bomb.write_text('\n'.join(lines + ['waypoints: *a9']) + '\n')
    code, _, err = _main(capsys, 'plan', bomb)
    assert code == 2 and err.strip() == (f'quadflight plan: {bomb}: its aliases (*name) expand it to more than '
                                         '1,000,000 values: refused')
    many = tmp_path / 'many.yaml'
    points = [f'  - [{0.01 * i:.2f}, 0.0, 1.0]' for i in range(5000)]
    points[2500] = '  - [1.0, x, 1.0]'
    many.write_text('name: many\nwaypoints:\n' + '\n'.join(points) + '\n')
    code, _, err = _main(capsys, 'plan', many)
    assert code == 2 and err.strip() == (f"quadflight plan: {many}: waypoints[2500] = [1.0, 'x', 1.0] must be "
                                         '[x, y, z] in metres (numbers)')
    typo = tmp_path / 'typo.yaml'
    typo.write_text(MISSION.replace('speed: 0.5', 'sped: 0.5'))
    code, _, err = _main(capsys, 'plan', typo)
    assert code == 2 and "trajectory.sped is not a known key (did you mean 'speed'?)" in err


def test_ros_names_and_domain_are_refused_in_one_line_before_anything_starts(capsys, tmp_path, monkeypatch):
    out = tmp_path / 'b'
    code, _, err = _main(capsys, 'record', '--out', out, 'not a topic!')
    assert code == 2 and err.startswith("quadflight record: topic 'not a topic!' refused: topic name must not")
    assert len(err.strip().splitlines()) == 1 and not out.exists()
    code, _, err = _main(capsys, 'record', '--out', out, 'bad//topic')   # refused only where rcl resolves it
    assert (code, err) == (2, "quadflight record: topic 'bad//topic' refused: topic name must not contain repeated "
                              "'/'\n") and not out.exists()
    code, _, err = _main(capsys, 'arm', '--namespace', 'bad ns!', '--timeout-s', '1')
    assert code == 2 and err.startswith("quadflight arm: --namespace 'bad ns!' refused: namespace must not")
    assert len(err.strip().splitlines()) == 1
    monkeypatch.setenv('ROS_DOMAIN_ID', '250')
    for argv in (['land', '--timeout-s', '1'], ['record', '--out', out]):
        code, _, err = _main(capsys, *argv)
        assert code == 2 and err.strip() == (f'quadflight {argv[0]}: ROS_DOMAIN_ID=\'250\' refused: must be an '
                                             "integer from 0 to 232 (Fast DDS's range)")
    assert not out.exists()


def test_report_into_a_directory_with_a_foreign_metrics_json_is_one_line(capsys, tmp_path):
    out = tmp_path / 'out'
    out.mkdir()
    (out / 'metrics.json').write_text('{not json')
    code, _, err = _main(capsys, 'report', _foreign_bag(tmp_path / 'bag'), '--out', out)
    assert code == 2 and err.startswith(f'quadflight report: --out {out}: its metrics.json is not one report wrote')
    assert len(err.strip().splitlines()) == 1 and (out / 'metrics.json').read_text() == '{not json'


def test_plan_on_a_full_disk_leaves_nothing_and_names_the_path(capsys, mission, tmp_path, monkeypatch):
    import errno

    import numpy as np

    def full(path, *args, **kwargs):   # the CSV's write fails half way, as on a full filesystem
        Path(path).write_text('t_s,pos_x\n0.0,')
        raise OSError(errno.ENOSPC, 'No space left on device')
    monkeypatch.setattr(np, 'savetxt', full)
    out = tmp_path / 'out' / 't.json'
    code, _, err = _main(capsys, 'plan', mission, '--out', out, '--csv', '10')
    assert code == 2 and err.strip() == (f'quadflight plan: --csv {out.with_suffix(".csv")}: cannot write it (No '
                                         'space left on device); nothing written')
    assert list(out.parent.iterdir()) == []


def test_fly_says_when_the_controller_is_not_the_profiles(capsys, tmp_path):
    (tmp_path / 'afile').write_text('mine\n')
    run_dir = tmp_path / 'afile' / 'run'   # refused when it is made, once the mission is planned: nothing flies
    code, out, err = _main(capsys, 'fly', REPO_ROOT / 'config/missions/maze.yaml', '--controller', 'pd',
                           '--control-profile', 'config/control_se3.yaml', '--out', run_dir)
    assert code == 2 and 'cannot create or write it' in err, err
    assert 'note: flying pd with the gains of /' in out   # file arguments are made absolute
    assert ('control_se3.yaml, a profile for se3 (its controller:); --controller wins: drop it to fly se3') in out


def test_a_vehicle_gain_that_is_text_names_the_field_and_the_file(capsys, tmp_path):
    vehicle = tmp_path / 'v.yaml'
    text = (REPO_ROOT / 'config/vehicles/crazyflie.yaml').read_text()
    vehicle.write_text(text.replace('  kp: [3000.0, 3000.0, 3000.0]', '  kp: stiff'))
    mission = tmp_path / 'm.yaml'
    mission.write_text(MISSION + f'vehicle: {vehicle}\n')
    code, _, err = _main(capsys, 'plan', mission)
    assert code == 2 and f"{vehicle}: attitude_gains.kp = 'stiff' must be three finite numbers >= 0" in err
