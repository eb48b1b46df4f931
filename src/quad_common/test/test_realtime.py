"""quad_common.realtime: every thread of the process set, those appearing meanwhile too; the system's refusal
names the parameter, the value and how to grant it; 0 touches nothing."""

import errno
import os
import subprocess
import sys

import pytest

from quad_common.realtime import apply_or_report, apply_realtime_priority


class Threads:
    """A process whose threads appear while they are being set (a Fast DDS thread started meanwhile)."""

    def __init__(self, *batches):
        self.batches, self.calls, self.set = list(batches), 0, []

    def tids(self):
        self.calls += 1
        return sorted({t for b in self.batches[:self.calls] for t in b})

    def setter(self, tid, policy, param):
        self.set.append((tid, policy, param.sched_priority))


def test_every_thread_and_those_started_meanwhile_get_sched_fifo_at_the_priority():
    threads = Threads([1, 2, 3], [4], [5, 6])
    assert apply_realtime_priority(30, threads.tids, threads.setter) == 'SCHED_FIFO 30 (6 threads)'
    assert threads.set == [(t, os.SCHED_FIFO, 30) for t in (1, 2, 3, 4, 5, 6)]


def test_zero_is_off_and_touches_nothing():
    threads = Threads([1, 2])
    assert apply_realtime_priority(0, threads.tids, threads.setter).startswith('off')
    assert threads.set == []


def test_a_thread_gone_meanwhile_is_skipped():
    threads = Threads([1, 2, 3])

    def setter(tid, policy, param):
        if tid == 2:
            raise ProcessLookupError(errno.ESRCH, 'No such process')
        threads.setter(tid, policy, param)

    assert apply_realtime_priority(5, threads.tids, setter).startswith('SCHED_FIFO 5')
    assert [t for t, _, _ in threads.set] == [1, 3]


def test_the_systems_refusal_names_the_parameter_the_value_and_how_to_grant_it():
    def setter(tid, policy, param):
        raise PermissionError(errno.EPERM, 'Operation not permitted')

    with pytest.raises(PermissionError) as refused:
        apply_realtime_priority(20, Threads([1]).tids, setter)
    said = refused.value.strerror
    assert said.startswith('realtime_priority = 20: SCHED_FIFO refused by the system (Operation not permitted)')
    for how in ('CAP_SYS_NICE', 'ulimit -r', 'limits.conf', 'rtprio', 'realtime_priority: 0'):
        assert how in said


@pytest.mark.parametrize('priority', [-1, 100])
def test_a_priority_outside_0_to_99_is_refused(priority):
    with pytest.raises(ValueError, match=f'realtime_priority = {priority} refused'):
        apply_realtime_priority(priority, Threads([1]).tids, Threads([1]).setter)


def test_a_node_told_no_says_so_as_an_error_and_runs_on():
    def setter(tid, policy, param):
        raise PermissionError(errno.EPERM, 'Operation not permitted')

    errors = []
    said, refused = apply_or_report(20, errors.append, Threads([1]).tids, setter)
    assert refused and said.startswith('refused: realtime_priority = 20: SCHED_FIFO refused')
    assert errors == [said.removeprefix('refused: ')]
    assert apply_or_report(0, errors.append) == ('off (SCHED_OTHER)', False) and len(errors) == 1


FREEZE_PROBE = '''
import gc, sys
from quad_common.realtime import freeze_startup_heap
garbage = [[i] for i in range(50_000)]                 # start-up objects that stay alive
cycle = []; cycle.append(cycle); del cycle              # start-up garbage: collected before the freeze
frozen = freeze_startup_heap()
scanned = []
gc.callbacks.append(lambda phase, info: scanned.append(len(gc.get_objects(2))) if phase == 'start' else None)
gc.collect()
print(frozen, scanned[0])
'''


def test_the_start_up_heap_is_frozen_so_a_full_collection_scans_only_what_came_after():
    """A full collection holds the interpreter lock, stopping every thread (a bridge's setpoints, a pose on its way)
    for as long as it scans: after the freeze it no longer scans the start-up heap."""
    done = subprocess.run([sys.executable, '-c', FREEZE_PROBE], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    frozen, scanned = done.stdout.split()
    assert int(frozen) > 50_000 and int(scanned) < 1_000
