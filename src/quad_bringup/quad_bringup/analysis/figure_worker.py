"""Figures of a finished flight in a process of their own (`quadflight fly` starts it with the graph).

It imports matplotlib and the report while the flight runs (most of its cost), then reads one JSON line on
stdin, {"flight": PICKLE, "out": DIR} (the report.Flight fly has loaded already, pickled; or {"bag": BAG, ...}
to load it here), draws DIR/figures/*.png on every core (report_figures.PARTS: the graph has stopped by then; the
parts are forked from this process, so matplotlib is imported once) and answers one JSON line on stdout:
{"figures": [paths relative to DIR]} or {"error": message}. FigureWorker is fly's side of it.
"""

import json
import os
import pickle
import subprocess
import sys
import tempfile
from pathlib import Path


class FigureWorker:
    """A process started with the graph that imports matplotlib and the report while the flight runs, then
    draws the figures of the finished bag (quad_bringup.analysis.figure_worker): the verdict does not wait for them."""

    def __init__(self, popen):
        self.popen = popen

    @classmethod
    def start(cls, env):
        popen = subprocess.Popen([sys.executable, '-m', 'quad_bringup.analysis.figure_worker'], env=env, text=True,
                                 stdin=subprocess.PIPE, stdout=subprocess.PIPE, start_new_session=True)
        return cls(popen)

    def draw(self, flight, out_dir: Path) -> list[str]:
        """The figure paths written (relative to out_dir); raises RuntimeError with the worker's message."""
        with tempfile.NamedTemporaryFile(suffix='.pickle') as f:
            pickle.dump(flight, f, protocol=pickle.HIGHEST_PROTOCOL)
            f.flush()
            try:
                out, _ = self.popen.communicate(json.dumps({'flight': f.name, 'out': str(out_dir)}) + '\n')
            except BaseException:   # a signal to fly while drawing: the worker ends with it
                self.cancel()
                raise
        answer = json.loads(out.strip().splitlines()[-1]) if out.strip() else {'error': 'no answer'}
        if 'error' in answer:
            raise RuntimeError(answer['error'])
        return answer['figures']

    def cancel(self):
        if self.popen.poll() is None:
            self.popen.kill()
            self.popen.wait()


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


def main():
    # the imports are the point: they overlap the flight; the report module (rosbags, the ROS messages) only for a
    # bag to load here, as a pickled Flight needs quad_bringup.analysis.metrics alone
    import matplotlib  # noqa: F401

    from quad_bringup.analysis import metrics, report_figures  # noqa: F401
    line = sys.stdin.readline()
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
        print(json.dumps(answer), flush=True)
    except BrokenPipeError:   # fly is gone (a signal while drawing): nobody to answer, nothing to say
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    return 0


if __name__ == '__main__':
    # once the answer is out and every figure file closed, tearing down matplotlib's modules and the flight only
    # delays fly, which waits for this process's exit to reap it (on the 2-core machine at load 11-13: 0.24-0.55 s
    # from the answer to the exit, 0.003-0.009 s without). It holds nothing the operating system does not release:
    # no DDS participant, no shared memory, no child (its parts are reaped).
    from quad_common.lifeline import exit_now

    exit_now(main())
