"""Refusals before start-up: `--help` and every command refusing an option or an input file, run as a user types
them (`./quadflight ARGS` from a directory of small input files), with the floors of this machine beside them.
Prints one markdown section."""

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
QUADFLIGHT = ROOT / 'quadflight'
RUNS = 3
GOAL_S = 0.3
HEAVY = ('numpy', 'scipy', 'rclpy', 'matplotlib', 'rosbags', 'numba')
MISSION = 'name: tiny\nwaypoints:\n  - [0.0, 0.0, 1.0]\n  - [1.0, 0.0, 1.0]\n'
INPUTS = {
    'ok.yaml': MISSION,
    'badwp.yaml': 'name: tiny\nwaypoints:\n  - [0.0, 0.0, 1.0]\n  - [1.0, 0.0, up]\n',
    'badspeed.yaml': MISSION + 'trajectory:\n  speed: -3\n',
    'badveh.yaml': 'name: noinertia\nmass_kg: 0.03\narm_length_m: 0.046\nk_eta: 2.3e-8\nk_m: 7.8e-10\n'
                   'rotor_speed_min_radps: 0.0\nrotor_speed_max_radps: 2500.0\n',
    'withbadveh.yaml': MISSION + 'vehicle: badveh.yaml\n',
    'afile': 'not a directory\n',
    'badspec.yaml': 'missions: [/nonexistent.yaml]\ncontrollers: [pd]\n',
}
COMMANDS = [
    '--help',
    'plan /nonexistent.yaml', 'plan emptydir', 'plan ok.yaml --speed -1', 'plan ok.yaml --csv 10',
    'plan ok.yaml --time-allocation nope', 'plan ok.yaml --out ok.yaml', 'plan badwp.yaml', 'plan badspeed.yaml',
    'plan withbadveh.yaml',
    'fly /nonexistent.yaml', 'fly config/missions/maze.yaml --controller nope', 'fly ok.yaml --speed -1',
    'fly ok.yaml --time-allocation nope', 'fly ok.yaml --time-limit-factor 0', 'fly ok.yaml --position-tolerance -1',
    'fly ok.yaml --vehicle /nonexistent.yaml', 'fly ok.yaml --control-profile /nonexistent.yaml',
    'fly ok.yaml --plant nope', 'fly ok.yaml --disturbances nope', 'fly ok.yaml --out afile', 'fly badwp.yaml',
    'fly badspeed.yaml', 'fly withbadveh.yaml', 'fly ok.yaml --vehicle badveh.yaml',
    'fleet /nonexistent.yaml', 'fleet ok.yaml',
    'report /nonexistent', 'report /nonexistent --vehicle badveh.yaml', 'report /nonexistent --settle -1',
    'identify /nonexistent', 'identify /nonexistent --latency-s 5', 'identify /nonexistent --out emptydir',
    'replay /nonexistent', 'replay /nonexistent --vehicle /nonexistent.yaml', 'replay /nonexistent --vehicle ok.yaml',
    'sweep /nonexistent.yaml', 'sweep badspec.yaml', 'tune /nonexistent.yaml', 'tune badspec.yaml',
    'record --out OUT bad_topic!', 'arm --timeout-s -1', 'arm --namespace 1bad', 'land --off',
]


def run_once(argv: list[str], cwd: Path, env: dict) -> tuple[float, float, float, int, str]:
    """(wall s, CPU s, peak MiB, exit code, stderr) of one whole process."""
    with tempfile.TemporaryFile('w+') as err:
        start = time.monotonic()
        proc = subprocess.Popen(argv, cwd=cwd, env=env, stdout=subprocess.DEVNULL, stderr=err)
        _, status, usage = os.wait4(proc.pid, 0)
        wall_s = time.monotonic() - start
        err.seek(0)
        return (wall_s, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024, os.waitstatus_to_exitcode(status),
                err.read())


def fastest(argv, cwd, env):
    return min((run_once(argv, cwd, env) for _ in range(RUNS)), key=lambda r: r[0])


def heavy_imports(args: list[str], cwd: Path, env: dict) -> list[str]:
    """The heavy modules the command imports (-X importtime, through PYTHONPROFILEIMPORTTIME)."""
    err = run_once([str(QUADFLIGHT), *args], cwd, dict(env, PYTHONPROFILEIMPORTTIME='1'))[4]
    names = {line.rsplit('|', 1)[-1].strip().split('.')[0] for line in err.splitlines()
             if line.startswith('import time')}
    return [m for m in HEAVY if m in names]


def main():
    env = dict(os.environ)
    env.pop('ROS_DOMAIN_ID', None)
    rows, over = [], []
    with tempfile.TemporaryDirectory(prefix='bench_refusals-') as tmp:
        cwd = Path(tmp)
        for name, text in INPUTS.items():
            (cwd / name).write_text(text)
        (cwd / 'emptydir').mkdir()
        (cwd / 'config').symlink_to(ROOT / 'config')
        floors = {what: fastest([sys.executable, '-c', code], cwd, env)
                  for what, code in (('`python -c pass`', 'pass'), ('`python -c "import numpy, yaml"`',
                                                                     'import numpy, yaml'))}
        fastest([str(QUADFLIGHT), '--help'], cwd, env)   # untimed: the page cache
        for command in COMMANDS:
            args = command.split()
            wall_s, cpu_s, mib, code, _ = fastest([str(QUADFLIGHT), *args], cwd, env)
            heavy = heavy_imports(args, cwd, env)
            rows.append(f'| `{command}` | {code} | {wall_s:.2f} | {cpu_s:.2f} | {mib:.0f} | '
                        f'{", ".join(heavy) or "-"} |')
            if wall_s >= GOAL_S:
                over.append(command)
            print(f'{command}: {wall_s:.2f} s, exit {code}', file=sys.stderr)
        load = os.getloadavg()[0]
    print('## Refusals before start-up (bench_refusals)\n')
    print(f'Each command run as `./quadflight ARGS` from a directory of small input files (a valid two-waypoint '
          f'mission `ok.yaml`, one with a non-numeric waypoint `badwp.yaml`, one with `speed: -3`, one naming a '
          f'vehicle file without inertia, that file `badveh.yaml`, an empty directory, a file `afile`, a sweep spec '
          f'naming a missing mission `badspec.yaml`), {RUNS} runs each, the fastest wall time with its CPU time '
          f'(user + system) and peak memory (the operating system\'s accounting of the whole process); heavy '
          f'imports: {", ".join(HEAVY)} among the modules `-X importtime` lists. Exit 0 for `--help`, 2 for a '
          f'refusal. Goal: under {GOAL_S} s of wall time. Load average (1 min) at the end: {load:.2f}.\n')
    print('Floors on this machine: ' + '; '.join(f'{what} {r[0]:.2f} s wall ({r[1]:.2f} s CPU)'
                                                  for what, r in floors.items()) + '.\n')
    print('| command | exit | wall (s) | CPU (s) | peak MiB | heavy imports |')
    print('|---|---:|---:|---:|---:|---|')
    print('\n'.join(rows))
    print(f'\n{len(COMMANDS) - len(over)} of {len(COMMANDS)} under {GOAL_S} s' +
          (f'; over it: {", ".join(f"`{c}`" for c in over)}' if over else '') + '.')


if __name__ == '__main__':
    main()
