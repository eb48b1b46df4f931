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
BASELINE = 'df5190a'   # main before fly's nodes shared one process (f5909f4 no longer passes its own bag check)
MISSION = ROOT / 'config' / 'missions' / 'maze.yaml'


def tree_env(tree: Path) -> dict:
    pkgs = sorted(str(p) for p in (tree / 'src').glob('quad_*'))
    return dict(os.environ, PYTHONPATH=os.pathsep.join(pkgs), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')


def fly_once(tree: Path, out: Path, timing=False) -> tuple[float, float, str]:
    """(wall s, CPU s of fly and every process it waited for, its stderr) of one whole command."""
    env = tree_env(tree)
    if timing:
        env['QUADFLIGHT_TIMING'] = '1'
    cmd = [sys.executable, '-m', 'quad_bringup.cli', 'fly', str(MISSION), '--speed', '0.5', '--out', str(out),
           '--quiet']
    with tempfile.TemporaryFile('w+') as stdout, tempfile.TemporaryFile('w+') as stderr:
        start = time.monotonic()
        proc = subprocess.Popen(cmd, env=env, cwd=tree, stdout=stdout, stderr=stderr)
        _, status, usage = os.wait4(proc.pid, 0)   # its rusage counts the children it reaped, theirs too
        wall_s = time.monotonic() - start
        proc.returncode = os.waitstatus_to_exitcode(status)
        stdout.seek(0)
        stderr.seek(0)
        out_text, err_text = stdout.read(), stderr.read()
    if proc.returncode != 0:
        raise SystemExit(f'bench_fly: {tree}: fly failed ({proc.returncode}):\n{out_text}{err_text}')
    return wall_s, usage.ru_utime + usage.ru_stime, err_text


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
        cpus = {name: [] for name in trees}
        loads = []
        phases = ''
        for i in range(args.runs + 1):   # run 0: untimed warm-up of each
            for name, tree in trees.items():
                wall_s, cpu_s, stderr = fly_once(tree, tmp / f'{name.split()[0]}-{i}', timing=name == 'new')
                if i:
                    walls[name].append(wall_s)
                    cpus[name].append(cpu_s)
                    loads.append(os.getloadavg()[0])
                if name == 'new':
                    phases = stderr
    print('### The whole `quadflight fly` command (maze, 0.5 m/s, 16.7 s simulated)\n')
    print(f'`bench/run fly`: {args.runs} interleaved runs each after one untimed warm-up; wall time of the whole '
          'process as a user waits for it, figures included, and the CPU of fly and every process it started '
          f'(user + system). Load average (1 min) after each run: {min(loads):.1f}-{max(loads):.1f}.\n')
    print('| command | median wall (s) | min - max (s) | median CPU (s) | min - max (s) | goal |')
    print('|---|---:|---:|---:|---:|---|')
    for name in trees:
        goal = '< 4 s wall, < 4 s CPU' if name == 'new' else 'baseline, same run'
        w, c = walls[name], cpus[name]
        print(f'| {name} | {statistics.median(w):.2f} | {min(w):.2f} - {max(w):.2f} | {statistics.median(c):.2f} | '
              f'{min(c):.2f} - {max(c):.2f} | {goal} |')
    marks = [line for line in phases.splitlines() if line.startswith('[')]
    if marks:
        print('\nPhases of the last new run (QUADFLIGHT_TIMING=1, seconds since the command started):\n')
        print('```')
        print('\n'.join(marks))
        print('```')


if __name__ == '__main__':
    main()
