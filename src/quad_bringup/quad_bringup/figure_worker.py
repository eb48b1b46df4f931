"""Figures of a finished flight in a process of their own (`quadflight fly` starts it with the graph).

It imports matplotlib and the report while the flight runs (most of its cost), then reads one JSON line on
stdin, {"flight": PICKLE, "out": DIR} (the report.Flight fly has loaded already, pickled; or {"bag": BAG, ...}
to load it here), draws DIR/figures/*.png and answers one JSON line on stdout: {"figures": [paths relative to
DIR]} or {"error": message}.
"""

import json
import pickle
import sys
from pathlib import Path


def main():
    import matplotlib  # noqa: F401 (the import is the point: it overlaps the flight)

    from quad_bringup import report, report_figures  # noqa: F401
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
            flight = report.load_flight(request['bag'])
        figures = [str(Path(f).relative_to(out)) for f in report.draw_figures(flight, out)]
        answer = {'figures': figures}
    except Exception as exc:  # any failure is an answer, not a traceback on fly's terminal
        answer = {'error': f'{type(exc).__name__}: {exc}'}
    print(json.dumps(answer), flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
