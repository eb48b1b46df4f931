"""fly's figures' process forked from fly (quad_bringup.analysis.figure_worker.FigureWorker): it draws every figure,
holds none of fly's descriptors, dies with fly, and is started as a module instead where fly has threads. Each case
runs in a process of its own: pytest's may have threads (DDS's, from other tests), and only a one-thread process
forks."""

import json
import os
import pickle
import select
import subprocess
import sys

import pytest
from test_report import make_bag

from quad_bringup.analysis.report import load_flight
from quad_bringup.analysis.report_figures import FIGURES

FLY = '''
import json, os, pickle, sys, threading, time
from quad_bringup.analysis.figure_worker import FigureWorker
flight_path, out, mode = sys.argv[1:4]
lock = os.open(flight_path, os.O_RDONLY)   # stands for fly's lock on its run directory
if mode == 'threads':
    threading.Thread(target=threading.Event().wait, daemon=True).start()
worker = FigureWorker.prepare()
forked = worker.child is not None
if mode == 'orphan':
    print(json.dumps({'pid': worker.child.pid}), flush=True)
    os._exit(0)
def files(pid):
    for fd in os.listdir(f'/proc/{pid}/fd'):
        try:
            yield os.readlink(f'/proc/{pid}/fd/{fd}')
        except FileNotFoundError:   # closed while listed
            pass
held, deadline = [flight_path], time.monotonic() + 20   # until the child has closed what it inherited
while forked and flight_path in held and time.monotonic() < deadline:
    held = list(files(worker.child.pid))
worker.begin(dict(os.environ))
kind = type(worker.child).__name__
with open(flight_path, 'rb') as f:
    figures = worker.draw(pickle.load(f), out)
print(json.dumps({'kind': kind, 'held': held, 'figures': figures, 'ended': worker.child.poll() is not None}))
'''


@pytest.fixture(scope='module')
def flight_pickle(tmp_path_factory):
    tmp = tmp_path_factory.mktemp('flight')
    path = tmp / 'flight.pickle'
    with open(path, 'wb') as f:
        pickle.dump(load_flight(make_bag(tmp / 'bag')), f)
    return path


def _fly(flight_pickle, out, mode):
    done = subprocess.run([sys.executable, '-c', FLY, str(flight_pickle), str(out), mode], text=True,
                          capture_output=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_a_one_thread_fly_forks_the_worker_which_draws_every_figure_and_holds_none_of_its_files(flight_pickle,
                                                                                                  tmp_path):
    answer = _fly(flight_pickle, tmp_path, 'one thread')
    assert answer['kind'] == '_ForkedChild'
    assert str(flight_pickle) not in answer['held']          # fly's lock is fly's alone
    assert sorted(answer['figures']) == sorted(f'figures/{name}' for name, _ in FIGURES)
    assert all((tmp_path / f).stat().st_size > 0 for f in answer['figures'])
    assert answer['ended']                                    # reaped once it has answered


def test_a_fly_with_threads_starts_the_worker_as_a_module(flight_pickle, tmp_path):
    answer = _fly(flight_pickle, tmp_path, 'threads')
    assert answer['kind'] == 'Popen'
    assert sorted(answer['figures']) == sorted(f'figures/{name}' for name, _ in FIGURES)


def test_the_forked_worker_dies_with_fly(flight_pickle, tmp_path):
    """fly killed before the figures (os._exit: no cleanup of its own): its forked worker does not outlive it."""
    pid = _fly(flight_pickle, tmp_path, 'orphan')['pid']
    try:
        pidfd = os.pidfd_open(pid)
    except ProcessLookupError:
        return   # gone already
    try:
        assert select.select([pidfd], [], [], 60)[0], f'the forked worker {pid} outlived fly'
    finally:
        os.close(pidfd)
