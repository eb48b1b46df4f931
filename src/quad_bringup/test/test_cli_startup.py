"""`quadflight --help` and each command's help page import nothing a help page does not need: no ROS client library,
no scipy, matplotlib or numba (each costs seconds on a loaded machine), and the top-level page no command module at
all. A behaviour, not a timing: each page is drawn in a fresh interpreter and its sys.modules read."""

import json
import os
import subprocess
import sys

import pytest

from quad_bringup import cli

HEAVY = ('rclpy', 'scipy', 'matplotlib', 'numba')
PROBE = """
import json, sys
from quad_bringup import cli
try:
    cli.main(sys.argv[1:])
except SystemExit:
    pass
print(json.dumps(sorted(sys.modules)), file=sys.stderr)
"""


def imported_by(*argv) -> set[str]:
    done = subprocess.run([sys.executable, '-c', PROBE, *argv], capture_output=True, text=True, timeout=120)
    return {name.partition('.')[0] if name.split('.')[0] in HEAVY + ('numpy',) else name
            for name in json.loads(done.stderr.strip().splitlines()[-1])}


def test_the_top_level_help_imports_no_command():
    modules = imported_by('--help')
    assert not modules & set(HEAVY + ('numpy',))
    assert not [m for m in modules if m.startswith('quad_bringup.commands.')]


@pytest.mark.parametrize('command', sorted(cli.SUBCOMMANDS))
def test_a_command_help_page_imports_no_heavy_module(command):
    assert not imported_by(command, '--help') & set(HEAVY)


@pytest.mark.parametrize('argv', [('fly', 'no_such_mission.yaml'),
                                  ('fly', 'config/missions/maze.yaml', '--speed', '-1')],
                         ids=['missing-file', 'bad-speed'])
def test_a_fly_refused_before_start_up_imports_no_ros_client_and_no_bag_library(argv):
    """The refusal is printed before rclpy, rosbags and matplotlib are imported (seconds on a loaded machine);
    they come with the start-up of the graph."""
    modules = imported_by(*argv)
    assert not modules & {'rclpy', 'matplotlib', 'numba', 'rosbags'}, sorted(modules & {'rclpy', 'rosbags'})


REFUSAL_PROBE = """
import json, sys
from quad_bringup import cli
code = cli.main(sys.argv[1:])
print(json.dumps({'code': code, 'modules': sorted(sys.modules)}), file=sys.stderr)
"""
MISSION = 'name: tiny\nwaypoints:\n  - [0.0, 0.0, 1.0]\n  - [1.0, 0.0, 1.0]\n'
BAD_WAYPOINT = 'name: tiny\nwaypoints:\n  - [0.0, 0.0, 1.0]\n  - [1.0, 0.0, up]\n'
# refused on the command line or for a file that is not there: nothing heavy, numpy included
OPTION_REFUSALS = {
    'plan-missing-file': ('plan', 'missing.yaml'),
    'plan-bad-speed': ('plan', 'm.yaml', '--speed', '-1'),
    'plan-csv-without-out': ('plan', 'm.yaml', '--csv', '10'),
    'fly-missing-file': ('fly', 'missing.yaml'),
    'fly-bad-speed': ('fly', 'm.yaml', '--speed', '-1'),
    'fly-missing-vehicle': ('fly', 'm.yaml', '--vehicle', 'missing.yaml'),
    'fleet-missing-file': ('fleet', 'missing.yaml'),
    'report-missing-bag': ('report', 'no_bag'),
    'report-bad-settle': ('report', 'no_bag', '--settle', '-1'),
    'identify-missing-bag': ('identify', 'no_bag'),
    'identify-bad-latency': ('identify', 'no_bag', '--latency-s', '5'),
    'replay-no-model': ('replay', 'no_bag'),
    'replay-missing-bag': ('replay', 'no_bag', '--vehicle', 'm.yaml'),
    'sweep-missing-spec': ('sweep', 'missing.yaml'),
    'arm-bad-timeout': ('arm', '--timeout-s', '-1'),
    'land-off': ('land', '--off'),
}
# refused for what an input file holds or for a name it must hold (pure Python checks: quad_common.vehicle_file,
# quad_trajectory.mission_file, quad_control.controller_names, quad_sim.disturbance_file): no numpy either
CONTENT_REFUSALS = {
    'plan-bad-waypoint': (('plan', 'bad.yaml'), "waypoints[1] = [1.0, 0.0, 'up']"),
    'plan-bad-speed': (('plan', 'badspeed.yaml'), 'speed = -3 must be a finite number > 0'),
    'plan-vehicle-without-inertia': (('plan', 'withbadveh.yaml'), 'badveh.yaml: inertia_kgm2 = None'),
    'fly-bad-waypoint': (('fly', 'bad.yaml'), "waypoints[1] = [1.0, 0.0, 'up']"),
    'fly-bad-speed': (('fly', 'badspeed.yaml'), 'speed = -3 must be a finite number > 0'),
    'fly-vehicle-without-inertia': (('fly', 'withbadveh.yaml'), 'badveh.yaml: inertia_kgm2 = None'),
    'fly-bad-vehicle': (('fly', 'm.yaml', '--vehicle', 'badveh.yaml'), 'badveh.yaml: inertia_kgm2 = None'),
    'fly-unknown-controller': (('fly', 'm.yaml', '--controller', 'nope'), "--controller 'nope' refused: must be"),
    'fly-unknown-plant': (('fly', 'm.yaml', '--plant', 'nope'), "--plant 'nope' refused: must be one of"),
    'fly-bad-disturbances': (('fly', 'm.yaml', '--disturbances', 'nope'), "disturbances = 'nope': no such profile"),
    'fly-out-a-file': (('fly', 'm.yaml', '--out', 'afile'), '--out afile: a file, not a directory'),
    'fleet-not-a-fleet': (('fleet', 'm.yaml'), 'not a fleet mission'),
    'report-bad-vehicle': (('report', 'no_bag', '--vehicle', 'badveh.yaml'), 'badveh.yaml: inertia_kgm2 = None'),
}
# numpy, nothing heavier: a module that imports numpy at its top (tune's)
NUMPY_ONLY_REFUSALS = {
    'tune-missing-spec': (('tune', 'missing.yaml'), 'tune refused: spec missing.yaml: file not found'),
}


def refused(tmp_path, *argv) -> tuple[int, list[str], set[str]]:
    """(exit code, stderr lines, top-level modules imported) of `quadflight ARGV` in a fresh interpreter."""
    env = {k: v for k, v in os.environ.items() if k != 'ROS_DOMAIN_ID'}
    done = subprocess.run([sys.executable, '-c', REFUSAL_PROBE, *argv], capture_output=True, text=True,
                          timeout=120, cwd=tmp_path, env=env)
    lines = done.stderr.strip().splitlines()
    assert lines, done.stdout
    result = json.loads(lines[-1])
    return result['code'], lines[:-1], {name.partition('.')[0] for name in result['modules']}


@pytest.fixture
def inputs(tmp_path):
    (tmp_path / 'm.yaml').write_text(MISSION)
    (tmp_path / 'bad.yaml').write_text(BAD_WAYPOINT)
    (tmp_path / 'badspeed.yaml').write_text(MISSION + 'trajectory:\n  speed: -3\n')
    (tmp_path / 'badveh.yaml').write_text('name: noinertia\nmass_kg: 0.03\narm_length_m: 0.046\nk_eta: 2.3e-8\n'
                                          'k_m: 7.8e-10\nrotor_speed_min_radps: 0.0\nrotor_speed_max_radps: 2500.0\n')
    (tmp_path / 'withbadveh.yaml').write_text(MISSION + 'vehicle: badveh.yaml\n')
    (tmp_path / 'afile').write_text('not a directory\n')
    return tmp_path


@pytest.mark.parametrize('argv', OPTION_REFUSALS.values(), ids=OPTION_REFUSALS.keys())
def test_an_option_or_missing_file_refusal_imports_nothing_heavy(inputs, argv):
    """Checked before numpy, scipy, rclpy, matplotlib and rosbags are imported: one line, exit 2, nothing left."""
    before = sorted(inputs.iterdir())
    code, lines, modules = refused(inputs, *argv)
    assert code == 2 and len(lines) == 1, lines
    assert not modules & set(HEAVY + ('numpy', 'rosbags')), sorted(modules & set(HEAVY + ('numpy', 'rosbags')))
    assert sorted(inputs.iterdir()) == before


@pytest.mark.parametrize(('argv', 'said'), CONTENT_REFUSALS.values(), ids=CONTENT_REFUSALS.keys())
def test_a_file_content_or_name_refusal_imports_nothing_heavy(inputs, argv, said):
    """Refused with the rule the later load applies (one function, pure Python): one line naming the field and the
    value, exit 2, nothing left, and neither numpy nor anything heavier imported."""
    before = sorted(inputs.iterdir())
    code, lines, modules = refused(inputs, *argv)
    assert code == 2 and len(lines) == 1 and said in lines[0], lines
    assert not modules & set(HEAVY + ('numpy', 'rosbags')), sorted(modules & set(HEAVY + ('numpy', 'rosbags')))
    assert sorted(inputs.iterdir()) == before


@pytest.mark.parametrize(('argv', 'said'), NUMPY_ONLY_REFUSALS.values(), ids=NUMPY_ONLY_REFUSALS.keys())
def test_a_refusal_by_a_numpy_module_imports_numpy_only(inputs, argv, said):
    before = sorted(inputs.iterdir())
    code, lines, modules = refused(inputs, *argv)
    assert code == 2 and len(lines) == 1 and said in lines[0], lines
    assert not modules & set(HEAVY + ('rosbags',)), sorted(modules & set(HEAVY + ('rosbags',)))
    assert sorted(inputs.iterdir()) == before


BLAS_PROBE = """
import os, sys
from quad_bringup import cli
seen = {}
def fake_fly(options, log, defer_figures):
    import numpy   # fly's own numpy: imported after the command set its BLAS threads, as the real fly's is
    seen['numpy_at_run'] = numpy_at_run
    seen['threads'] = os.environ.get('OPENBLAS_NUM_THREADS')
    raise SystemExit(0)
import quad_bringup.running.flight as flight
numpy_at_run = 'numpy' in sys.modules
flight.fly = fake_fly
try:
    cli.main(sys.argv[1:])
except SystemExit:
    pass
print(seen['numpy_at_run'], seen['threads'], file=sys.stderr)
"""


@pytest.mark.parametrize('preset, expected', [(None, '1'), ('2', '2')])
def test_fly_runs_numpy_s_blas_on_one_thread_unless_told(tmp_path, preset, expected):
    """fly and every process it starts (they inherit its environment) run OpenBLAS on one thread (commands.fly
    BLAS_THREADS): set before fly's own numpy import; a value the user set is kept."""
    env = {k: v for k, v in os.environ.items() if k != 'OPENBLAS_NUM_THREADS'}
    if preset is not None:
        env['OPENBLAS_NUM_THREADS'] = preset
    mission = tmp_path / 'm.yaml'
    mission.write_text('name: m\nwaypoints: [[0, 0, 1], [1, 0, 1]]\n')
    done = subprocess.run([sys.executable, '-c', BLAS_PROBE, 'fly', str(mission)], capture_output=True, text=True,
                          timeout=120, env=env)
    assert done.stderr.strip().splitlines()[-1] == f'False {expected}', done.stderr
