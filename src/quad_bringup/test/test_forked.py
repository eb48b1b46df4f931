"""quad_bringup.pools.forked: a child forked instead of a new interpreter. Each case runs in a fresh one-thread
process (pytest's may hold DDS threads, and only a one-thread process forks)."""

import json
import subprocess
import sys
import textwrap

PRELUDE = '''
import json, os, signal, subprocess, sys, threading
from quad_bringup.pools.forked import ForkedProcess, can_fork
'''


def _run(code: str, *args) -> dict:
    done = subprocess.run([sys.executable, '-c', PRELUDE + textwrap.dedent(code), *map(str, args)], text=True,
                          capture_output=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_the_child_runs_with_its_own_streams_session_and_signals_and_none_of_the_parents_files(tmp_path):
    answer = _run('''
        log = os.open(sys.argv[1], os.O_WRONLY | os.O_CREAT)
        secret = os.open(sys.argv[1], os.O_RDONLY)   # stands for fly's run-directory lock
        signal.signal(signal.SIGINT, lambda *_: None)     # fly's own handler
        def child():
            held = str(secret) in os.listdir('/proc/self/fd')
            print('pid', os.getpid(), 'session', os.getsid(0), 'secret open', held)
            print('SIGINT default', signal.getsignal(signal.SIGINT) is signal.default_int_handler)
            return 3
        process = ForkedProcess.start(child, stdin=0, stdout=log, stderr=log)
        print(json.dumps({'code': process.wait(), 'pid': process.pid, 'polled': process.poll()}))
    ''', tmp_path / 'log')
    log = (tmp_path / 'log').read_text()
    assert f'pid {answer["pid"]} session {answer["pid"]} secret open False' in log     # its own session
    assert 'SIGINT default True' in log
    assert answer['code'] == answer['polled'] == 3


def test_its_exit_status_comes_from_system_exit_or_an_exception_and_it_never_returns_into_the_parent():
    answer = _run('''
        def leave():
            sys.exit(5)
        def fail():
            raise RuntimeError('boom')
        codes = [ForkedProcess.start(f, stdin=0, stdout=1, stderr=2).wait() for f in (leave, fail)]
        print(json.dumps({'codes': codes, 'me': os.getpid()}))   # printed once: by this process only
    ''')
    assert answer['codes'] == [5, 1]


def test_wait_with_a_timeout_raises_while_it_runs_and_kill_ends_it():
    answer = _run('''
        process = ForkedProcess.start(lambda: signal.pause(), stdin=0, stdout=1, stderr=2)
        try:
            process.wait(timeout=0.05)
            timed_out = False
        except subprocess.TimeoutExpired:
            timed_out = True
        process.kill()
        print(json.dumps({'timed_out': timed_out, 'code': process.wait(timeout=30)}))
    ''')
    assert answer == {'timed_out': True, 'code': -9}


def test_only_a_process_of_one_thread_may_fork():
    answer = _run('''
        alone = can_fork()
        threading.Thread(target=threading.Event().wait, daemon=True).start()
        print(json.dumps({'alone': alone, 'with a thread': can_fork()}))
    ''')
    assert answer == {'alone': True, 'with a thread': False}
