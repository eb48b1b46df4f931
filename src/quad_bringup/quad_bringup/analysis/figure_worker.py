"""Figures of a finished flight in a process of their own (`quadflight fly` starts it with the graph).

It imports matplotlib and the report while the flight runs (most of its cost), then reads one JSON line,
{"flight": PICKLE, "out": DIR} (the report.Flight fly has loaded already, pickled; or {"bag": BAG, ...} to load it
here), draws DIR/figures/*.png on every core (report_figures.PARTS: the graph has stopped by then; the parts are
forked from this process, so matplotlib is imported once) and answers one JSON line: {"figures": [paths relative
to DIR]} or {"error": message}. As `python -m quad_bringup.analysis.figure_worker` it reads stdin and answers on
stdout. FigureWorker is fly's side of it: a child forked from fly while fly has one thread (it inherits fly's
interpreter, numpy and the analysis modules, ~0.2 s of CPU less than a new interpreter), or that module started.
"""

import json
import os
import pickle
import subprocess
import sys
import tempfile
from pathlib import Path

from quad_bringup.pools.forked import ForkedProcess, can_fork

GO = b'\n'   # the forked worker's first line: import now (fly sends it once the flight has started)


class FigureWorker:
    """fly's side of the figures' process: made before the graph starts (`prepare`), its imports begun once the
    flight has started (`begin`: they overlap the flight, which waits on the lockstep more than it computes, not
    the start-up, where every process computes at once), handed the finished flight (`draw`)."""

    def __init__(self):
        self.child = None   # _ForkedChild, or subprocess.Popen of the module
        self.begun = False

    @classmethod
    def prepare(cls):
        """Forks the worker now where this process has one thread (fly before its monitor's DDS threads): a fork
        of a process with other threads may hold their locks forever. Otherwise `begin` starts the module."""
        worker = cls()
        if can_fork():
            from quad_bringup.analysis import metrics  # noqa: F401 - the child's, inherited rather than imported
            worker.child = _ForkedChild.fork()
        return worker

    def begin(self, env=None):
        """Its imports start now (env: the started module's environment)."""
        if self.begun:
            return
        self.begun = True
        if self.child is None:
            self.child = subprocess.Popen([sys.executable, '-m', 'quad_bringup.analysis.figure_worker'],
                                          env=env, text=True, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                          start_new_session=True)
        else:
            self.child.go()

    def draw(self, flight, out_dir: Path) -> list[str]:
        """The figure paths written (relative to out_dir); raises RuntimeError with the worker's message."""
        self.begin()
        with tempfile.NamedTemporaryFile(suffix='.pickle') as f:
            pickle.dump(flight, f, protocol=pickle.HIGHEST_PROTOCOL)
            f.flush()
            try:
                out, _ = self.child.communicate(json.dumps({'flight': f.name, 'out': str(out_dir)}) + '\n')
            except BaseException:   # a signal to fly while drawing: the worker ends with it
                self.cancel()
                raise
        answer = json.loads(out.strip().splitlines()[-1]) if out.strip() else {'error': 'no answer'}
        if 'error' in answer:
            raise RuntimeError(answer['error'])
        return answer['figures']

    def cancel(self):
        if self.child is not None and self.child.poll() is None:
            self.child.kill()
            self.child.wait()


class _ForkedChild:
    """The worker forked from fly (quad_bringup.pools.forked), with Popen's poll, kill, wait and communicate
    (text in and out): it waits for GO, then imports and serves one request (serve)."""

    def __init__(self, process, requests: int, answers: int):
        self.process, self._requests, self._answers = process, requests, answers

    @classmethod
    def fork(cls):
        request_read, request_write = os.pipe()
        answer_read, answer_write = os.pipe()
        null = os.open(os.devnull, os.O_RDWR)
        try:
            process = ForkedProcess.start(lambda: _serve_forked(request_read, answer_write), stdin=null,
                                          stdout=null, stderr=2, keep=(request_read, answer_write))
        finally:
            for fd in (request_read, answer_write, null):
                os.close(fd)
        return cls(process, request_write, answer_read)

    @property
    def pid(self):
        return self.process.pid

    def go(self):
        try:
            os.write(self._requests, GO)
        except BrokenPipeError:   # it died: communicate reports no answer
            pass

    def communicate(self, text: str):
        try:
            with os.fdopen(self._requests, 'w') as requests:
                requests.write(text)
        except BrokenPipeError:
            pass
        with os.fdopen(self._answers) as answers:
            out = answers.read()
        self.process.wait()
        return out, None

    def poll(self):
        return self.process.poll()

    def kill(self):
        self.process.kill()

    def wait(self):
        return self.process.wait()


def _serve_forked(request_fd: int, answer_fd: int) -> int:
    from quad_common.lifeline import exit_now

    requests, answers = os.fdopen(request_fd), os.fdopen(answer_fd, 'w')
    exit_now(serve(requests, answers) if requests.readline() else 0)   # end of file: fly ended before GO
    return 1


def finish_figures(worker: FigureWorker, flight, run_dir: Path, metrics: dict, mark=lambda what: None) -> str | None:
    """Figures into run_dir/figures and their links into report.md; an error line, or None."""
    from quad_bringup.analysis.report import write_markdown

    try:
        figures = worker.draw(flight, run_dir)
    except (RuntimeError, ValueError, OSError) as exc:
        return f'figures not drawn: {exc}'
    write_markdown(metrics, run_dir, [run_dir / f for f in figures])
    mark('figures drawn')
    return None


def serve(requests, answers) -> int:
    """Imports matplotlib and the figures, then answers one request line (module docstring); the exit status."""
    # the imports are the point: they overlap the flight; the report module (rosbags, the ROS messages) only for a
    # bag to load here, as a pickled Flight needs quad_bringup.analysis.metrics alone
    import matplotlib  # noqa: F401

    from quad_bringup.analysis import metrics, report_figures  # noqa: F401
    line = requests.readline()
    if not line.strip():
        return 0  # fly ended before a bag: nothing to draw
    try:
        request = json.loads(line)
        out = Path(request['out'])
        if 'flight' in request:
            with open(request['flight'], 'rb') as f:
                flight = pickle.load(f)
        else:
            from quad_bringup.analysis import report

            flight = report.load_flight(request['bag'])
        drawn = report_figures.draw_run(flight, out, report_figures.PARTS)
        figures = [str(Path(f).relative_to(out)) for f in drawn]
        answer = {'figures': figures}
    except Exception as exc:  # any failure is an answer, not a traceback on fly's terminal
        answer = {'error': f'{type(exc).__name__}: {exc}'}
    try:
        answers.write(json.dumps(answer) + '\n')
        answers.flush()
    except BrokenPipeError:   # fly is gone (a signal while drawing): nobody to answer, nothing to say
        if answers is sys.stdout:
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    return 0


def main():
    return serve(sys.stdin, sys.stdout)


if __name__ == '__main__':
    # once the answer is out and every figure file closed, tearing down matplotlib's modules and the flight only
    # delays fly, which waits for this process's exit to reap it (on the 2-core machine at load 11-13: 0.24-0.55 s
    # from the answer to the exit, 0.003-0.009 s without). It holds nothing the operating system does not release:
    # no DDS participant, no shared memory, no child (its parts are reaped).
    from quad_common.lifeline import exit_now

    exit_now(main())
