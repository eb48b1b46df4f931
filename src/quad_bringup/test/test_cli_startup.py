"""`quadflight --help` and each command's help page import nothing a help page does not need: no ROS client library,
no scipy, matplotlib or numba (each costs seconds on a loaded machine), and the top-level page no command module at
all. A behaviour, not a timing: each page is drawn in a fresh interpreter and its sys.modules read."""

import json
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
