"""Nothing lost on a machine that is really busy. Two `quadflight fly` of the same mission at once beside
four busy-looping processes (on the 2-core machine: load ~6 from this test alone); the lockstep followers hold
the simulator, so each bag has every step sim_node published. The timeout is a hang guard only."""

import json
import subprocess
import sys

from rosbags.rosbag2 import Reader
from test_fly import QUADFLIGHT, TIMEOUT_S, mission

BUSY_LOOPS = 4
FLIES = 2


def test_two_flies_beside_four_busy_loops_record_every_step(tmp_path, ros_env):
    path = mission(tmp_path, [[0, 0, 1], [0.8, 0.4, 1.2], [1.5, 0, 1]])
    loops = [subprocess.Popen([sys.executable, '-c', 'while True: pass']) for _ in range(BUSY_LOOPS)]
    flies = []
    try:
        for k in range(FLIES):
            flies.append(subprocess.Popen([QUADFLIGHT, 'fly', str(path), '--out', str(tmp_path / f'run{k}'),
                                           '--quiet'], env=ros_env, stdout=subprocess.PIPE,
                                          stderr=subprocess.STDOUT, text=True))
        outputs = [fly.communicate(timeout=TIMEOUT_S)[0] for fly in flies]
    finally:
        for proc in loops + flies:
            if proc.poll() is None:
                proc.kill()
            proc.wait()
    for k, (fly, out) in enumerate(zip(flies, outputs)):
        assert fly.returncode == 0, f'fly {k}:\n{out}'
        run_dir = tmp_path / f'run{k}'
        record = json.loads((run_dir / 'metrics.json').read_text())['record']
        assert record['complete'] and record['gaps'] == [] and 'missing' not in record, (k, record)
        n = record['steps_published']
        assert record['odom_recorded'] == record['/clock_recorded'] == n > 100, (k, record)
        with Reader(run_dir / 'bag') as reader:      # the bag itself, not only what fly says of it
            counts = {c.topic: c.msgcount for c in reader.connections}
        assert counts['odom'] >= n and counts['/clock'] >= n, (k, counts)   # (steps after the count: more)
