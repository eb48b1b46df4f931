"""quadflight sweep / tune: offline flights per second per core beside `fly` through the ROS graph and rotorpy's
Environment.run on the same planned missions; a 1,000-flight sweep of 10 s flights on all cores; and a tune of
the se3 fast profile over the plant family (config/experiments/tune_se3_fast.yaml). Prints one markdown section.

--quick: fewer flights and a 2-generation tune (a check that the bench runs, not numbers to publish).
"""

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(p) for p in sorted((ROOT / 'src').glob('quad_*'))]

from quad_bringup.experiments import runs, sweep, tune  # noqa: E402
from quad_common.paths import resolve_config  # noqa: E402

MISSIONS = ['config/missions/window.yaml', 'config/missions/maze.yaml', 'config/missions/figure8.yaml']
TUNE_SPEC = ROOT / 'config' / 'experiments' / 'tune_se3_fast.yaml'


def offline_per_core(repeats: int) -> dict:
    """Serial flights in this process (the kernels loaded first): flights/s and simulated s per CPU s."""
    params = sweep.expand({'missions': MISSIONS, 'controllers': ['pd']})
    runs.run_one(params[0])
    sim_s = 0.0
    wall, cpu = time.perf_counter(), time.process_time()
    for _ in range(repeats):
        for p in params:
            sim_s += runs.run_one(p)['time_actual_s']
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    n = repeats * len(params)
    return {'flights': n, 'flights_per_cpu_s': n / cpu, 'rtf_cpu': sim_s / cpu, 'rtf_wall': sim_s / wall}


def graph_flights() -> dict:
    """`fly` through the graph (separate processes, DDS, bag, report) on the same missions, one at a time."""
    params = sweep.expand({'missions': MISSIONS, 'controllers': ['pd']}, mode='graph')
    sim_s, failures = 0.0, 0
    with tempfile.TemporaryDirectory(prefix='bench_sweep-') as tmp:
        start = time.perf_counter()
        for p in params:
            row = runs.run_one(p, tmp)
            sim_s += row['time_actual_s'] or 0.0
            failures += row['failed']
        wall = time.perf_counter() - start
    return {'flights': len(params), 'flights_per_s': len(params) / wall, 'rtf_wall': sim_s / wall,
            'failures': failures}


def thousand_flights(n: int) -> dict:
    """n runs of the window mission (10.4 s planned at 0.5 m/s): pd and the fast se3 profile, with and without
    odometry noise, seeds 0..n/4-1, through the local pool on all cores (pool start-up, table and summary
    included; figures not)."""
    spec = {'missions': ['config/missions/window.yaml'],
            'controllers': ['pd', {'name': 'se3-fast', 'profile': 'config/control_fast.yaml'}],
            'disturbances': ['none', 'mocap_noise'], 'seeds': max(1, n // 4)}
    with tempfile.TemporaryDirectory(prefix='bench_sweep-') as tmp:
        (Path(tmp) / 'spec.yaml').write_text(json.dumps(spec))
        start = time.perf_counter()
        rows, _ = sweep.run_sweep(Path(tmp) / 'spec.yaml', Path(tmp) / 'out', figures=False, log=lambda line: None)
        wall = time.perf_counter() - start
    sim_s = sum(r['time_actual_s'] or 0.0 for r in rows)
    cpu_s = sum(r['cpu_s'] for r in rows)
    return {'flights': len(rows), 'wall_s': wall, 'cpu_s': cpu_s, 'load': os.getloadavg()[0],
            'flights_per_s': len(rows) / wall, 'mean_flight_s': sim_s / len(rows),
            'failures': sum(r['failed'] for r in rows), 'cores': os.cpu_count()}


ROTORPY = '''
import json, sys, time
import numpy as np
from rotorpy.vehicles.multirotor import Multirotor
from rotorpy.vehicles.crazyflie_params import quad_params
from rotorpy.controllers.quadrotor_control import SE3Control
from rotorpy.environments import Environment

class Sampled:
    """Our planned mission, sampled at 100 Hz, as a rotorpy trajectory (linear interpolation of the samples)."""
    def __init__(self, d):
        self.t = np.array(d['t']); self.p = np.array(d['p']); self.v = np.array(d['v']); self.a = np.array(d['a'])
    def update(self, t):
        f = lambda arr: np.array([np.interp(t, self.t, arr[:, i]) for i in range(arr.shape[1])])
        p, v, a = f(self.p), f(self.v), f(self.a)
        z = np.zeros(3)
        return {'x': p[:3], 'x_dot': v[:3], 'x_ddot': a[:3], 'x_dddot': z, 'x_ddddot': z, 'yaw': p[3],
                'yaw_dot': v[3], 'yaw_ddot': a[3]}

missions = json.load(open(sys.argv[1]))
sim_s = 0.0
start = time.perf_counter()
for d in missions:
    x0 = {'x': np.array(d['p'][0][:3]), 'v': np.zeros(3), 'q': np.array([0, 0, 0, 1.0]), 'w': np.zeros(3),
          'wind': np.zeros(3), 'rotor_speeds': np.ones(4) * 1788.53}
    env = Environment(vehicle=Multirotor(quad_params, initial_state=x0), controller=SE3Control(quad_params),
                      trajectory=Sampled(d), sim_rate=100)
    env.run(t_final=d['t'][-1], use_mocap=False, terminate=False, plot=False, animate_bool=False, verbose=False)
    sim_s += d['t'][-1]
wall = time.perf_counter() - start
print(len(missions) / wall, sim_s / wall)
'''


def rotorpy_flights() -> dict:
    """rotorpy 3.0.0's Environment.run (its SE3 controller, 100 Hz) on the same planned missions."""
    from quad_trajectory.mission import load_mission, plan_mission

    data = []
    for m in MISSIONS:
        traj = plan_mission(load_mission(resolve_config(m))).trajectory.to_sampled(100.0)
        data.append({'t': (traj.times_s - traj.times_s[0]).tolist(), 'p': traj.position.tolist(),
                     'v': traj.velocity.tolist(), 'a': traj.acceleration.tolist()})
    try:
        from quad_bringup.peers.peer_venv import run_peer

        with tempfile.NamedTemporaryFile('w', suffix='.json', delete=False) as f:
            json.dump(data, f)
        out = run_peer(ROTORPY.replace('sys.argv[1]', repr(f.name)), timeout_s=600).split()
        os.unlink(f.name)
        return {'flights_per_s': float(out[-2]), 'rtf_wall': float(out[-1])}
    except Exception as exc:  # the peer is optional: report why it is missing
        return {'error': f'{type(exc).__name__}: {str(exc).splitlines()[-1] if str(exc) else ""}'[:80]}


def tune_se3_fast(quick: bool) -> dict:
    spec = sweep.load_spec(TUNE_SPEC)
    if quick:
        spec['optimizer'] = {**spec.get('optimizer', {}), 'maxiter': 1, 'popsize': 2}
    with tempfile.TemporaryDirectory(prefix='bench_tune-') as tmp:
        (Path(tmp) / 'spec.yaml').write_text(json.dumps(spec))
        start = time.perf_counter()
        summary = tune.run_tune(Path(tmp) / 'spec.yaml', Path(tmp) / 'out', log=lambda line: None)
        summary['wall_s'] = time.perf_counter() - start
        evaluations = (Path(tmp) / 'out' / 'evaluations.csv').read_text()
    summary['evaluation_lines'] = evaluations.splitlines()
    return summary


def fmt(value, spec='.1f'):
    return '-' if value is None else format(value, spec)


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('--quick', action='store_true')
    args = parser.parse_args()
    per_core = offline_per_core(1 if args.quick else 5)
    print(f'  offline {per_core}', file=sys.stderr, flush=True)
    thousand = thousand_flights(40 if args.quick else 1000)
    print(f'  sweep {thousand}', file=sys.stderr, flush=True)
    graph = graph_flights()
    print(f'  graph {graph}', file=sys.stderr, flush=True)
    peer = rotorpy_flights()
    print(f'  rotorpy {peer}', file=sys.stderr, flush=True)
    tuned = tune_se3_fast(args.quick)
    print(f'  tune {tuned["cost_before_m"]} -> {tuned["cost_after_m"]}', file=sys.stderr, flush=True)

    print('### Many flights: quadflight sweep and tune\n')
    print(f'Missions {", ".join(Path(m).stem for m in MISSIONS)} at their own 0.5 m/s, seed pd gains, one flight at '
          'a time. Offline: `fly_offline` (the same simulator and controller code as the graph, no ROS) in one '
          'process; '
          'real-time factor per core = simulated seconds / CPU seconds of that process (the machine is shared, so '
          'wall-clock rates vary with the load beside it). Graph: `fly` through the ROS graph (4 processes, DDS, bag, '
          'report; start-up included). rotorpy 3.0.0: `Environment.run` (its SE3 controller, 100 Hz) on the same '
          'planned trajectories, in its own venv.\n')
    print('| measurement | offline loop | `fly` (ROS graph) | rotorpy Environment.run | goal |')
    print('|---|---:|---:|---:|---|')
    peer_fps = fmt(peer.get('flights_per_s'), '.2f') if 'error' not in peer else f'n/a ({peer["error"]})'
    peer_rtf = fmt(peer.get('rtf_wall')) + 'x' if 'error' not in peer else 'n/a'
    print(f'| flights/s, one core | {per_core["flights_per_cpu_s"]:.2f} (per CPU s) | {graph["flights_per_s"]:.3f} | '
          f'{peer_fps} | |')
    print(f'| real-time factor, one core | {per_core["rtf_cpu"]:.0f}x per CPU s ({per_core["rtf_wall"]:.0f}x wall) | '
          f'{graph["rtf_wall"]:.1f}x wall | {peer_rtf} wall | >= 200x per core |')
    print(f'| {thousand["flights"]:,}-flight sweep of {thousand["mean_flight_s"]:.1f} s flights, local pool, '
          f'{thousand["cores"]} cores | {thousand["wall_s"]:.0f} s wall at load {thousand["load"]:.1f} '
          f'({thousand["flights_per_s"]:.1f} flights/s, {thousand["failures"]} failed); flights\' CPU '
          f'{thousand["cpu_s"]:.0f} s = {thousand["cpu_s"] / thousand["cores"]:.0f} s on {thousand["cores"]} '
          'idle cores '
          f'| | | < 120 s |')
    print()
    print('Sweep: window mission, pd and the se3 fast profile, without and with odometry noise (mocap_noise), '
          'seeds 0..249; wall time from the command to the written table and summary (pool start-up included).\n')
    print(f'#### Tune of the se3 fast profile over the plant family\n\n`quadflight tune '
          f'{TUNE_SPEC.relative_to(ROOT)}`: {tuned["aggregate"]} of the per-run cost (RMSE plus tilt and saturation '
          f'penalties, 1 m for a failed run) over 2 missions at 2 m/s x 4 plant family members (nominal, '
          f'20 % heavier, hover thrust 6 % low, an ArduPilot-like lagged attitude target) x drag with 1 m/s wind; '
          f'scipy differential '
          f'evolution, {tuned["evaluations"]} profiles evaluated ({tuned["runs"]} flights) in '
          f'{tuned["wall_s"]:.0f} s.\n')
    print('| | cost (m) | ' + ' | '.join(name for name, _ in _tuned_keys(tuned)) + ' |')
    print('|---|---:|' + '---:|' * len(_tuned_keys(tuned)))
    for label, gains, cost in (('start (config/control_fast.yaml)', tuned['base_gains'], tuned['cost_before_m']),
                               ('tuned', tuned['best_gains'], tuned['cost_after_m'])):
        print(f'| {label} | {cost:.4f} | ' + ' | '.join(fmt(gains[k], '.3g') for _, k in _tuned_keys(tuned)) + ' |')
    if tuned.get('verify'):
        print('\nThe tuned profile through the ROS graph (`fly`; the spec\'s first plant member and disturbance: '
              'nominal, drag with 1 m/s wind) beside the offline loop:\n')
        print('| mission | RMSE offline (m) | RMSE graph (m) | graph |\n|---|---:|---:|---|')
        for r in tuned['verify']:
            print(f'| {r["mission"]} | {fmt(r["offline_rmse_m"], ".4f")} | {fmt(r["graph_rmse_m"], ".4f")} | '
                  f'{"completed" if r["graph_completed"] else r["graph_failure"]} |')
    best = min(tuned['evaluation_lines'][1:], key=lambda line: float(line.split(',')[-7]))
    print(f'\nEvaluation table (evaluations.csv, best row): `{tuned["evaluation_lines"][0]}` / `{best}`')


def _tuned_keys(tuned):
    keys = ['kp_x', 'kd_x', 'kp_z', 'kd_z', 'attitude_lead_s', 'disturbance_time_constant_s']
    return [(k, k) for k in keys if k in tuned['best_gains']]


if __name__ == '__main__':
    main()
