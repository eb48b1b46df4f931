"""The whole `quadflight fly` command: wall time a user waits, against a baseline tree in the same run.

Flies config/missions/maze.yaml at 0.5 m/s (16.7 s simulated) with the command line as a user types it, new and
baseline interleaved (a busy machine slows both alike), after one untimed run of each (numba caches, page
cache). The baseline is `git archive BASE` (default: main before the start-up and reliability change) run with
this .venv. Also the phases of the new command's last run (QUADFLIGHT_TIMING=1). Prints one markdown section.
"""

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BASELINE = '1361a52'   # main before quad_bringup's sub-packages (f5909f4 no longer passes its own bag check)
MISSION = ROOT / 'config' / 'missions' / 'maze.yaml'


def tree_env(tree: Path) -> dict:
    pkgs = sorted(str(p) for p in (tree / 'src').glob('quad_*'))
    return dict(os.environ, PYTHONPATH=os.pathsep.join(pkgs), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')


def fly_once(tree: Path, out: Path, timing=False) -> tuple[float, str]:
    env = tree_env(tree)
    if timing:
        env['QUADFLIGHT_TIMING'] = '1'
    cmd = [sys.executable, '-m', 'quad_bringup.cli', 'fly', str(MISSION), '--speed', '0.5', '--out', str(out),
           '--quiet']
    start = time.monotonic()
    done = subprocess.run(cmd, env=env, cwd=tree, capture_output=True, text=True, timeout=600)
    wall_s = time.monotonic() - start
    if done.returncode != 0:
        raise SystemExit(f'bench_fly: {tree}: fly failed ({done.returncode}):\n{done.stdout}{done.stderr}')
    return wall_s, done.stderr


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('--runs', type=int, default=3)
    parser.add_argument('--base', default=BASELINE, help='git ref of the baseline tree (default %(default)s)')
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix='bench_fly-') as tmp:
        tmp = Path(tmp)
        base = tmp / 'base'
        base.mkdir()
        archive = subprocess.run(['git', '-C', str(ROOT), 'archive', args.base], capture_output=True, check=True)
        subprocess.run(['tar', '-x', '-C', str(base)], input=archive.stdout, check=True)
        trees = {'new': ROOT, f'baseline ({args.base})': base}
        walls = {name: [] for name in trees}
        phases = ''
        for i in range(args.runs + 1):   # run 0: untimed warm-up of each
            for name, tree in trees.items():
                wall_s, stderr = fly_once(tree, tmp / f'{name.split()[0]}-{i}', timing=name == 'new')
                if i:
                    walls[name].append(wall_s)
                if name == 'new':
                    phases = stderr
    load = os.getloadavg()[0]
    print('### The whole `quadflight fly` command (maze, 0.5 m/s, 16.7 s simulated)\n')
    print(f'`bench/run fly`: {args.runs} interleaved runs each after one untimed warm-up; wall time of the whole '
          f'process as a user waits for it, figures included. Load average at the end: {load:.1f}.\n')
    print('| command | median wall (s) | min (s) | max (s) | goal |')
    print('|---|---:|---:|---:|---|')
    for name, values in walls.items():
        goal = '< 4 s' if name == 'new' else 'baseline, same run'
        print(f'| {name} | {statistics.median(values):.2f} | {min(values):.2f} | {max(values):.2f} | {goal} |')
    marks = [line for line in phases.splitlines() if line.startswith('[')]
    if marks:
        print('\nPhases of the last new run (QUADFLIGHT_TIMING=1, seconds since the command started):\n')
        print('```')
        print('\n'.join(marks))
        print('```')


if __name__ == '__main__':
    main()
