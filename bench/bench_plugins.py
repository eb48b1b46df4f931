"""A controller we did not write, flown through quadflight: rotorpy 3.0.0's SE3Control, unchanged from its package
(the peers' venv, quad_bringup.peers.peer_venv), as `--controller rotorpy.controllers.quadrotor_control:SE3Control`,
beside rotorpy's own Environment.run of the same controller on the same planned trajectory and vehicle parameters; and
the cost per tick of the plugin path. Prints one markdown section.

rotorpy is made importable in quadflight's processes without its venv: a directory holding only a link to the
installed `rotorpy` package goes on PYTHONPATH (both venvs pin the same numpy and scipy; SE3Control imports numpy and
scipy only, torch being optional), what a user does with `pip install rotorpy` in the environment that runs the
controller.
"""

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(p) for p in sorted((ROOT / 'src').glob('quad_*'))]

import numpy as np  # noqa: E402

from quad_bringup.offline.closed_loop import LoopOptions, fly_offline, load_control_profile  # noqa: E402
from quad_bringup.peers.peer_venv import run_peer  # noqa: E402
from quad_bringup.peers.rotorpy_peer import SE3CONTROL, rotorpy_dir  # noqa: E402
from quad_common.paths import resolve_config  # noqa: E402
from quad_common.types import AttitudeSetpoint, Reference, State  # noqa: E402
from quad_control.plugins import ControllerPlugin, make_controller, vehicle_params  # noqa: E402
from quad_control.position import Limits  # noqa: E402
from quad_trajectory.mission import load_mission, plan_mission  # noqa: E402

MISSIONS = ('config/missions/figure8.yaml', 'config/missions/maze.yaml')
GRAPH_MISSION = 'config/missions/figure8.yaml'

ROTORPY = '''
import json, sys
import numpy as np
from rotorpy.vehicles.multirotor import Multirotor
from rotorpy.vehicles.crazyflie_params import quad_params
from rotorpy.controllers.quadrotor_control import SE3Control
from rotorpy.environments import Environment

class Sampled:
    """Our planned mission, sampled at 100 Hz, as a rotorpy trajectory (linear interpolation of the samples)."""
    def __init__(self, d):
        self.t = np.array(d['t']); self.p = np.array(d['p']); self.v = np.array(d['v']); self.a = np.array(d['a'])
        self.j = np.array(d['j'])
    def update(self, t):
        f = lambda arr: np.array([np.interp(t, self.t, arr[:, i]) for i in range(arr.shape[1])])
        p, v, a, j = f(self.p), f(self.v), f(self.a), f(self.j)
        return {'x': p[:3], 'x_dot': v[:3], 'x_ddot': a[:3], 'x_dddot': j[:3], 'x_ddddot': np.zeros(3), 'yaw': p[3],
                'yaw_dot': v[3], 'yaw_ddot': a[3]}

data = json.load(open(sys.argv[1]))
out = {}
for d in data['missions']:
    params = dict(quad_params, **data['params'])
    w0 = np.sqrt(params['mass'] * 9.81 / (4 * params['k_eta']))
    for abstraction in ('cmd_motor_speeds',):
        x0 = {'x': np.array(d['p'][0][:3]), 'v': np.zeros(3), 'q': np.array([0, 0, 0, 1.0]), 'w': np.zeros(3),
              'wind': np.zeros(3), 'rotor_speeds': np.full(4, w0)}
        env = Environment(vehicle=Multirotor(params, initial_state=x0, control_abstraction=abstraction),
                          controller=SE3Control(params), trajectory=Sampled(d), sim_rate=100)
        r = env.run(t_final=d['t'][-1], use_mocap=False, terminate=False, plot=False, animate_bool=False,
                    verbose=False)
        err = np.linalg.norm(r['state']['x'] - r['flat']['x'], axis=1)
        out[d['name'] + ' ' + abstraction] = {'rmse_m': float(np.sqrt(np.mean(err ** 2))), 'max_m': float(err.max())}
print(json.dumps(out))
'''


class TrivialOurs(ControllerPlugin):
    """The cheapest controller of our interface: what the plugin path itself costs."""

    def update(self, state, reference, dt_s):
        return AttitudeSetpoint()


HOVER_Q = np.array([0.0, 0.0, 0.0, 1.0])


class TrivialFlightsim:
    """The cheapest flightsim / rotorpy controller: the adapter's conversions and checks are the cost."""

    def __init__(self, quad_params):
        self.thrust_n = quad_params['mass'] * 9.81

    def update(self, t, state, flat_output):
        return {'cmd_thrust': self.thrust_n, 'cmd_q': HOVER_Q}


def plant_params(vehicle) -> dict:
    """What rotorpy's Crazyflie (its crazyflie_params) flies with of ours: the same mass, inertia, thrust and moment
    coefficients and rotor speed range (equal numbers), rotor drag off (our simulator has none without a disturbance
    profile). Its own arm (0.043 m), 72 ms motors and ctatt attitude PD (kp 310, kd 57) are kept: with our 15 ms
    motors its Environment at 100 Hz does not hold a hover level (rotor speeds 660-2150 rad/s, seen here)."""
    p = vehicle_params(vehicle)
    keep = ('mass', 'Ixx', 'Iyy', 'Izz', 'k_eta', 'k_m', 'rotor_speed_min', 'rotor_speed_max')
    return {**{k: float(p[k]) for k in keep}, 'k_d': 0.0, 'k_z': 0.0, 'c_Dx': 0.0, 'c_Dy': 0.0, 'c_Dz': 0.0}


def rotorpy_runs(trajectories, vehicle) -> dict:
    with tempfile.NamedTemporaryFile('w', suffix='.json', delete=False) as f:
        json.dump({'missions': trajectories, 'params': plant_params(vehicle)}, f)
    try:
        return json.loads(run_peer(ROTORPY.replace('sys.argv[1]', repr(f.name)), timeout_s=900).splitlines()[-1])
    finally:
        os.unlink(f.name)


def sampled(mission_path):
    mission = load_mission(resolve_config(mission_path))
    traj = plan_mission(mission).trajectory.to_sampled(100.0)
    t = traj.times_s - traj.times_s[0]
    jerk = np.array([traj.reference(s).jerk for s in traj.times_s])
    return mission, {'name': Path(mission_path).stem, 't': t.tolist(), 'p': traj.position.tolist(),
                     'v': traj.velocity.tolist(), 'a': traj.acceleration.tolist(),
                     'j': np.column_stack([jerk, np.zeros(len(t))]).tolist()}


def graph_flight(tmp: Path, path: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=f'{path}{os.pathsep}{os.environ.get("PYTHONPATH", "")}')
    run = tmp / 'graph'
    done = subprocess.run([str(ROOT / 'quadflight'), 'fly', str(resolve_config(GRAPH_MISSION)), '--controller',
                           SE3CONTROL, '--out', str(run), '--quiet'], env=env, capture_output=True, text=True,
                          timeout=600)
    if done.returncode != 0:
        return {'error': (done.stdout + done.stderr).strip().splitlines()[-1][:100]}
    return json.loads((run / 'metrics.json').read_text())


def tick_cost_us(name, vehicle, n=20000) -> float:
    """Median wall time of update() (ControlLoop's call) for a hovering state, in microseconds."""
    control = make_controller(name, None, vehicle, Limits.of(vehicle))
    state, ref = State(position=np.array([0.0, 0.0, 1.0])), Reference(position=np.array([0.1, 0.0, 1.0]))
    times = []
    for _ in range(n):
        start = time.perf_counter()
        control.update(state, ref, 0.01)
        times.append(time.perf_counter() - start)
    return 1e6 * float(np.median(times))


def main():
    with tempfile.TemporaryDirectory(prefix='bench_plugins-') as tmp:
        tmp = Path(tmp)
        path = rotorpy_dir(tmp)
        sys.path.insert(0, str(path))
        rows, trajectories, vehicle = [], [], None
        for m in MISSIONS:
            mission, traj = sampled(m)
            vehicle = mission.vehicle
            trajectories.append(traj)
            ours_se3 = fly_offline(resolve_config(m), LoopOptions(*load_control_profile('config/control_se3.yaml')))
            theirs = fly_offline(resolve_config(m), LoopOptions(controller=SE3CONTROL))
            rows.append((traj['name'], traj['t'][-1], theirs, ours_se3))
            print(f'  {traj["name"]}: offline {theirs["rmse_m"]:.4f} (ours se3 {ours_se3["rmse_m"]:.4f})',
                  file=sys.stderr, flush=True)
        peer = rotorpy_runs(trajectories, vehicle)
        print(f'  rotorpy {peer}', file=sys.stderr, flush=True)
        graph = graph_flight(tmp, path)
        print(f'  graph {graph.get("rmse_m", graph)}', file=sys.stderr, flush=True)
        costs = {name: tick_cost_us(name, vehicle) for name in
                 ('se3', 'bench_plugins:TrivialOurs', 'bench_plugins:TrivialFlightsim',
                  'quad_control.templates.my_controller:MyController',
                  'quad_control.templates.flightsim_controller:SE3Control', SE3CONTROL)}

    print('### Your controller: rotorpy\'s SE3Control through quadflight\n')
    print('rotorpy 3.0.0\'s `SE3Control`, unchanged from its package, flown by quadflight as `--controller '
          f'{SE3CONTROL}` (the adapter of quad_control.plugins: our state and plan as its dicts, its `cmd_thrust` and '
          '`cmd_q` as the attitude / thrust setpoint for the vehicle\'s own attitude loop), beside rotorpy\'s own '
          '`Environment.run` of the same controller on the same planned trajectory (our plan sampled at 100 Hz, '
          'jerk included) on the same Crazyflie (quadflight: config/vehicles/crazyflie.yaml, the controller built '
          'with `quad_control.plugins.vehicle_params` of it; rotorpy: its crazyflie_params with our mass, inertia, '
          'thrust and moment coefficients and rotor speed range, which are the same numbers, and drag off as in our '
          'simulator without a disturbance profile). rotorpy: its default `cmd_motor_speeds`, the controller\'s own '
          'attitude law (kp_att 544, kd_att 46.6) makes motor speeds (its `cmd_ctatt` abstraction, which would fly '
          '`cmd_q` and `cmd_thrust` as quadflight does, gives the same states in 3.0.0\'s Environment, identical to '
          'the last digit here, so it is no second reference). They differ in what lies under the setpoint: the '
          'attitude loop (quadflight\'s simulator flies `cmd_q` with the vehicle\'s eq. 6, kp 3000, kd 300), the '
          'motors (rotorpy 72 ms, ours 15 ms: with ours its 100 Hz Environment does not hold a level hover) and the '
          'arm (0.043 / 0.046 m). RMSE of position against the plan: rotorpy over the plan\'s duration, quadflight '
          'over the report\'s window (to completion).\n')
    print('| mission (plan s) | quadflight offline loop | quadflight `fly` (ROS graph) | rotorpy Environment.run | '
          'our se3 (control_se3.yaml), offline |')
    print('|---|---:|---:|---:|---:|')
    for name, duration, theirs, ours in rows:
        g = f'{100 * graph["rmse_m"]:.2f} cm' if name == Path(GRAPH_MISSION).stem and 'rmse_m' in graph else \
            ('-' if name != Path(GRAPH_MISSION).stem else graph.get('error', '-'))
        ms = peer.get(f'{name} cmd_motor_speeds', {})
        print(f'| {name} ({duration:.1f} s) | {100 * theirs["rmse_m"]:.2f} cm | {g} | '
              f'{100 * ms.get("rmse_m", float("nan")):.2f} cm | {100 * ours["rmse_m"]:.2f} cm |')
    print(f'\nCost of one update as ControlLoop calls it (median of 20000, hovering; wall time, one process, load '
          f'{os.getloadavg()[0]:.1f}): the trivial classes are what the plugin path costs (conversions, timing, '
          'checks, clamps); goal: under 50 us over our se3.\n')
    print('| controller | us per update | over our se3 |')
    print('|---|---:|---:|')
    for name, us in costs.items():
        print(f'| `{name}` | {us:.1f} | {us - costs["se3"]:+.1f} |')
    print()


if __name__ == '__main__':
    main()
