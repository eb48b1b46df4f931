"""Minimum-snap solve time against segment count: ours (banded, O(M)) vs the seed's dense A^-1 b vs
rotorpy's MinSnap vs minsnap-trajectories. Prints one markdown section.

Same problem for all: random-walk waypoints (x, y, z), rest-to-rest, 7th-order pieces, segment times from
length / 1 m/s; each peer is timed inside its own process (quad_bringup.peers.peer_venv). A size is skipped where the
growth measured so far predicts more than 60 s.
"""

import json
import sys
import time

import numpy as np

from quad_bringup.peers.peer_venv import run_peer  # noqa: E402
from quad_trajectory import planner, solver  # noqa: E402

SIZES = [10, 100, 1000, 10000]
LIMIT_S = 60.0
SEED = 620


def waypoints(m: int) -> np.ndarray:
    rng = np.random.default_rng(SEED)
    steps = rng.normal(size=(m, 3))
    steps /= np.linalg.norm(steps, axis=1, keepdims=True)   # 1 m legs
    return np.vstack([np.zeros(3), np.cumsum(steps, axis=0)]) + [0, 0, 1]


def best_of(fn, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def ours(m):
    w = waypoints(m)
    return best_of(lambda: planner.plan(w, options=planner.PlanOptions(speed_mps=1.0, time_allocation='proportional')),
                   5 if m <= 1000 else 3)


def dense(m):
    w = np.column_stack([waypoints(m), np.zeros(m + 1)])
    durations = np.linalg.norm(np.diff(w[:, :3], axis=0), axis=1)
    return best_of(lambda: solver.solve_dense_reference(durations, w, 4, 'continuity'), 3 if m <= 100 else 1)


_PEER_HEADER = f"""
import json, time, numpy as np
rng = np.random.default_rng({SEED})
def waypoints(m):
    steps = rng.normal(size=(m, 3)); steps /= np.linalg.norm(steps, axis=1, keepdims=True)
    return np.vstack([np.zeros(3), np.cumsum(steps, axis=0)]) + [0, 0, 1]
"""

PEER_CODE = {
    'rotorpy MinSnap': _PEER_HEADER + """
from rotorpy.trajectories.minsnap import MinSnap
w = waypoints(M)
t0 = time.perf_counter()
MinSnap(w, v_avg=1.0, v_max=100.0, verbose=False)
print(json.dumps(time.perf_counter() - t0))
""",
    'minsnap-trajectories': _PEER_HEADER + """
import minsnap_trajectories as ms
w = waypoints(M)
t = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(w, axis=0), axis=1))])
refs = [ms.Waypoint(time=float(ti), position=p) for ti, p in zip(t, w)]
z = np.zeros(3)   # rest-to-rest through jerk, as ours (its default leaves the end jerk free)
refs[0] = ms.Waypoint(time=0.0, position=w[0], velocity=z, acceleration=z, jerk=z)
refs[-1] = ms.Waypoint(time=float(t[-1]), position=w[-1], velocity=z, acceleration=z, jerk=z)
t0 = time.perf_counter()
ms.generate_trajectory(refs, degree=7, idx_minimized_orders=4, num_continuous_orders=4, algorithm='closed-form')
print(json.dumps(time.perf_counter() - t0))
""",
}


def peer(name):
    def run(m):
        return json.loads(run_peer(f'M = {m}\n' + PEER_CODE[name], timeout_s=LIMIT_S).strip())
    return run


def measure(fn, sizes, exponent_floor=1.0):
    """{size: seconds or None (skipped: predicted > LIMIT_S, or a smaller size timed out or failed)}."""
    out, last = {}, None
    for m in sizes:
        if out and list(out.values())[-1] is None:
            out[m] = None
            continue
        if last is not None:
            (m0, t0), (m1, t1) = last
            growth = max(exponent_floor, np.log(t1 / t0) / np.log(m1 / m0)) if m0 != m1 else exponent_floor
            if t1 * (m / m1) ** growth > LIMIT_S:
                out[m] = None
                continue
        try:
            out[m] = fn(m)
        except Exception as exc:   # a peer failing at a size is reported, not fatal
            print(f'bench_trajectory: M={m}: {type(exc).__name__}: {str(exc)[:200]}', file=sys.stderr)
            out[m] = None
            continue
        last = ((last[1] if last else (m, out[m])), (m, out[m]))
    return out


def fmt(t, m):
    if t is None:
        return 'skipped (> 60 s)'
    return f'{t * 1e3:.1f} ms ({t / m * 1e6:.1f} us/seg)' if t < 10 else f'{t:.1f} s ({t / m * 1e3:.1f} ms/seg)'


def main():
    results = {'ours (banded, O(M))': measure(ours, SIZES),
               'seed dense A^-1 b': measure(dense, SIZES, exponent_floor=3.0)}
    for name in PEER_CODE:
        results[name] = measure(peer(name), SIZES, exponent_floor=2.0)   # QP / dense solvers: superlinear
    print('### Trajectory: minimum-snap solve time')
    print()
    print('Minimum-snap (7th order, rest-to-rest, continuity through the 6th derivative) through M + 1 random-walk '
          'waypoints with 1 m legs; time for the whole plan (ours: validation, allocation, assembly, banded solve; '
          'peers timed inside their own process, best of several runs for the fast ones). '
          'Sizes predicted to take over 60 s are skipped.')
    print()
    print('| segments M | ' + ' | '.join(results) + ' |')
    print('|---:|' + '---:|' * len(results))
    for m in SIZES:
        print(f'| {m} | ' + ' | '.join(fmt(r[m], m) for r in results.values()) + ' |')
    base = results['ours (banded, O(M))'][100]
    speedups = [f'{name} {r[100] / base:.0f}x' for name, r in results.items() if r.get(100) and r[100] != base]
    print()
    print(f'At M = 100 ours is faster than: {", ".join(speedups)}.')


if __name__ == '__main__':
    main()
