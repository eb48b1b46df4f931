"""The README's fly -> identify -> replay chain, its three lines as the README writes them, run from another
working directory than the checkout: the flight it names is one identify can read, and replay finds the model
identify wrote."""

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TIMEOUT_S = 540


def readme_chain() -> list[list[str]]:
    """The README lines that fly runs/figure8, identify it and replay it: options in [brackets] and comments
    dropped, ./quadflight made this checkout's."""
    lines = [line for line in (ROOT / 'README.md').read_text().splitlines()
             if re.match(r'\./quadflight (fly|identify|replay) .*runs/figure8\b', line)]
    assert [line.split()[1] for line in lines] == ['fly', 'identify', 'replay'], lines
    commands = []
    for line in lines:
        line = re.sub(r'\[[^\]]*\]', '', line.split('#')[0])
        words = line.split()
        commands.append([str(ROOT / 'quadflight'), *words[1:]])
    return commands


def test_the_readme_chain_flies_identifies_and_replays_from_another_directory(tmp_path, ros_env):
    fly, identify, replay = readme_chain()
    for command in (fly, identify, replay):
        done = subprocess.run(command, cwd=tmp_path, env=ros_env, capture_output=True, text=True, timeout=TIMEOUT_S)
        assert done.returncode == 0, f'{command}:\n{done.stdout}\n{done.stderr}'
    bag = tmp_path / 'runs' / 'figure8' / 'bag'
    assert (bag.parent / 'bag_profile.yaml').is_file() and (bag.parent / 'bag_vehicle.yaml').is_file()
    assert 'twin RMSE' in done.stdout and (bag.parent / 'bag_replay.png').stat().st_size > 10_000
