"""One writer per sweep directory, and nothing left running after a SIGKILL of sweep: a second sweep
into the same --out is refused while the first runs (before: 48 rows for 24 runs, a second CSV header inside
runs.csv); SIGKILL of the first ends its forkserver, workers and resource tracker; the next sweep resumes."""

import json
import os
import signal
import subprocess
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
QUADFLIGHT = str(ROOT / 'quadflight')
SPEC = {'missions': ['config/missions/maze.yaml'], 'controllers': ['pd'], 'seeds': 400,
        'disturbances': [{'name': 'wind', 'base': 'drag_wind', 'wind_mps': [0.5, 0.0, 0.0]}]}
WAIT_S = 120.0   # generous hang guards for a busy 2-core machine


def _children() -> dict[int, int]:
    """pid -> parent pid of every live (not zombie) process."""
    out = {}
    for entry in os.listdir('/proc'):
        if entry.isdigit():
            try:
                fields = Path(f'/proc/{entry}/stat').read_text().rsplit(')', 1)[1].split()
            except OSError:
                continue
            if fields[0] != 'Z':
                out[int(entry)] = int(fields[1])
    return out


def _descendants(pid: int) -> set[int]:
    tree, found, frontier = _children(), set(), {pid}
    while frontier:
        frontier = {p for p, parent in tree.items() if parent in frontier} - found
        found |= frontier
    return found


def _wait_for(condition, what):
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        if condition():
            return
        time.sleep(0.2)
    raise AssertionError(f'timed out after {WAIT_S} s waiting for {what}')


def test_a_second_sweep_is_refused_and_a_sigkilled_one_leaves_nothing_running(tmp_path):
    spec, out = tmp_path / 'spec.yaml', tmp_path / 'out'
    spec.write_text(json.dumps(SPEC))
    first = subprocess.Popen([QUADFLIGHT, 'sweep', str(spec), '--out', str(out), '--workers', '2', '--no-figures'],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        rows = out / 'runs.jsonl'
        _wait_for(lambda: rows.exists() and rows.read_text().count('\n') >= 2, 'the first sweep to finish 2 runs')
        second = subprocess.run([QUADFLIGHT, 'sweep', str(spec), '--out', str(out), '--workers', '1'],
                                capture_output=True, text=True, timeout=WAIT_S)
        assert second.returncode == 2 and 'another sweep or tune writes there now (sweep pid' in second.stderr, \
            second.stderr
        family = _descendants(first.pid)
        assert len(family) >= 3, f'expected a forkserver, 2 workers (and a resource tracker): {family}'
        os.kill(first.pid, signal.SIGKILL)
        first.wait(timeout=WAIT_S)
        _wait_for(lambda: not (family & set(_children())), f'{family & set(_children())} to end')
    finally:
        if first.poll() is None:
            os.killpg(first.pid, signal.SIGKILL)
    header_lines = (out / 'runs.csv').read_text().splitlines()
    assert header_lines[0] not in header_lines[1:], 'a second CSV header inside runs.csv'
    before = len((out / 'runs.jsonl').read_text().splitlines())
    resumed = subprocess.Popen([QUADFLIGHT, 'sweep', str(spec), '--out', str(out), '--workers', '1',
                                '--no-figures'], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                               start_new_session=True)
    try:   # the lock went with the killed sweep: the next one writes again
        _wait_for(lambda: len((out / 'runs.jsonl').read_text().splitlines()) > before, 'the resumed sweep')
    finally:
        os.killpg(resumed.pid, signal.SIGTERM)
        resumed.wait(timeout=WAIT_S)
