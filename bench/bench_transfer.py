"""Flight quality that transfers: every mission x plant family member x profile, in the offline loop.

The plant family (config/plant_family.yaml) stands for vehicles we did not tune on: slow motors, an autopilot's
own attitude loop (a PX4-like SO(3) cascade, an ArduPilot-like lagged target), a heavier vehicle, a wrong hover
thrust. Profiles: `default` is what `quadflight fly --controller se3` flies (config/control_se3.yaml);
`identified` is that profile with the attitude lead and thrust scale `quadflight identify` found in a bag of
one figure8 flight of the same member with the default profile. Each flight: 2 m/s average, the mission's
limits-aware allocation where the mission gives trajectory.limits (figure8, long_100), quad_bringup.closed_loop
(the graph's pieces and timing without DDS; RMSE and completion as `quadflight report` computes them).
Goal: default never diverges, completes, RMSE < 5 cm; identified RMSE < 2 cm.
"""

import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(p) for p in sorted((ROOT / 'src').glob('quad_*'))] + [str(ROOT / 'bench')]

from quad_bringup.closed_loop import LoopOptions, fly_offline, load_control_profile  # noqa: E402
from quad_bringup.identify import identify  # noqa: E402
from quad_bringup.report import load_flight  # noqa: E402
from quad_common.vehicle import load_plant_family  # noqa: E402
from quad_common.yaml_io import load_yaml  # noqa: E402
from quad_control.parameters import profile_parameters  # noqa: E402
from quad_trajectory.mission import load_mission  # noqa: E402

MISSIONS = ('maze', 'window', 'figure8', 'long_100')
SPEED_MPS = 2.0
DEFAULT_PROFILE = ROOT / 'config' / 'control_se3.yaml'
IDENTIFY_MISSION = 'figure8'


def _options(mission, member, gains, controller, **extra):
    path = ROOT / 'config' / 'missions' / f'{mission}.yaml'
    overrides = {'time_allocation': 'limits'} if load_mission(path).options.v_max_mps is not None else None
    return path, LoopOptions(controller=controller, gains=gains, speed_mps=SPEED_MPS, plan_overrides=overrides,
                             plant=member, **extra)


def identified_gains(member):
    """(gains with the identified lead and thrust scale, identification result) for one family member."""
    controller, gains = load_control_profile(DEFAULT_PROFILE)
    with tempfile.TemporaryDirectory(prefix='bench_transfer-') as tmp:
        path, options = _options(IDENTIFY_MISSION, member, gains, controller, bag_dir=Path(tmp) / 'bag')
        fly_offline(path, options)
        result = identify(load_flight(Path(tmp) / 'bag'))
    gains.attitude_lead_s = result['attitude_lead_s']
    gains.thrust_scale = result['thrust_scale']
    return gains, result


ROTORPY_LOOP = '''
import json, sys, numpy as np
sys.path[:0] = {paths!r}
from rotorpy.vehicles.multirotor import Multirotor
from rotorpy.vehicles.crazyflie_params import quad_params
from quad_common.sampled_trajectory import SampledTrajectory
from quad_common.types import State
from quad_common.vehicle import vehicle_from_dict
from quad_control.parameters import gains_from
from quad_control.position import Limits, PositionController
from scipy.spatial.transform import Rotation
data = np.load({npz!r})
trajectory = SampledTrajectory(data['t'], data['p'], data['v'], data['a'])
vehicle = vehicle_from_dict(json.loads({vehicle!r}))
control = PositionController({controller!r}, gains_from(json.loads({gains!r})), vehicle, Limits.of(vehicle))
start = trajectory.position[0]
w0 = np.sqrt(quad_params['mass'] * 9.81 / (4 * quad_params['k_eta']))
state = {{'x': start[:3].copy(), 'v': np.zeros(3), 'q': Rotation.from_euler('z', start[3]).as_quat(), 'w': np.zeros(3),
         'wind': np.zeros(3), 'rotor_speeds': np.full(4, w0)}}
plant = Multirotor(quad_params, initial_state=state, control_abstraction='cmd_ctatt')
log = []
for k in range(int((trajectory.duration_s + 3.0) * 100)):
    t = k * 0.01
    seen = State(position=state['x'], velocity=state['v'], quaternion=state['q'], body_rates=state['w'])
    sp, _ = control.update(seen, trajectory.reference(min(t, trajectory.duration_s)), 0.01 if k else 0.0)
    log.append([t, *state['x'], *state['v'], *Rotation.from_quat(state['q']).as_euler('ZYX')[::-1],
                sp.specific_force_mps2, *Rotation.from_quat(sp.quaternion).as_euler('ZYX')[::-1]])
    state = plant.step(state, {{'cmd_thrust': sp.specific_force_mps2 * vehicle.mass_kg, 'cmd_q': sp.quaternion}}, 0.01)
    if not np.all(np.isfinite(state['x'])) or np.linalg.norm(state['x'] - start[:3]) > 1e3:
        break
np.save({out!r}, np.array(log))
'''


def rotorpy_flight(mission, gains_values, tmp):
    """Our planner + position controller (pure cores) flying rotorpy 3.0.0's Multirotor (Crazyflie parameters: its own
    72 ms motors and SO(3) PD attitude loop, kp 310 / kd 57, its rotor drag) in the peers' venv; a Flight."""
    import json

    import numpy as np
    from peers import run_peer

    from quad_bringup.report import Flight
    from quad_common.paths import resolve_config
    from quad_common.yaml_io import load_yaml
    from quad_trajectory.mission import plan_mission
    path = ROOT / 'config' / 'missions' / f'{mission}.yaml'
    loaded = load_mission(path)
    overrides = {'time_allocation': 'limits'} if loaded.options.v_max_mps is not None else {}
    plan = plan_mission(loaded, speed_mps=SPEED_MPS, **overrides)
    trajectory = plan.trajectory.to_sampled(100.0)
    npz, out = Path(tmp) / f'{mission}.npz', Path(tmp) / f'{mission}-log.npy'
    np.savez(npz, t=trajectory.times_s, p=trajectory.position, v=trajectory.velocity, a=trajectory.acceleration)
    paths = [str(ROOT / 'src' / p) for p in ('quad_common', 'quad_control')]
    vehicle = load_yaml(resolve_config('config/vehicles/crazyflie.yaml'))
    run_peer(ROTORPY_LOOP.format(paths=paths, npz=str(npz), out=str(out), vehicle=json.dumps(vehicle),
                                 controller=gains_values.get('controller', 'se3'), gains=json.dumps(gains_values)),
             timeout_s=600)
    log = np.load(out)
    return Flight(odom_t=log[:, 0], position=log[:, 1:4], velocity=log[:, 4:7], euler=log[:, 7:10], traj_start_s=0.0,
                  trajectory=trajectory, waypoints=plan.waypoints, cmd_t=log[:, 0], cmd_specific_force=log[:, 10],
                  cmd_euler=log[:, 11:14])


def rotorpy_rows():
    """(identification, [(mission, default metrics, identified metrics)]) on rotorpy's plant, or the reason it is
    missing (the peer is optional)."""
    from quad_bringup.report import compute_metrics
    try:
        values = profile_parameters(load_yaml(DEFAULT_PROFILE))
        with tempfile.TemporaryDirectory(prefix='bench_transfer-rotorpy-') as tmp:
            result = identify(rotorpy_flight(IDENTIFY_MISSION, values, tmp))
            tuned = dict(values, attitude_lead_s=result['attitude_lead_s'], thrust_scale=result['thrust_scale'])
            rows = [(m, compute_metrics(rotorpy_flight(m, values, tmp)), compute_metrics(rotorpy_flight(m, tuned, tmp)))
                    for m in MISSIONS]
        return result, rows
    except Exception as exc:  # noqa: BLE001 -- reported in the table instead
        return f'{type(exc).__name__}: {str(exc).splitlines()[-1] if str(exc) else ""}', []


def fly(args):
    mission, member, gains = args
    controller, _ = load_control_profile(DEFAULT_PROFILE)
    m = fly_offline(*_options(mission, member, gains, controller))
    return m['completed'] and not m.get('stopped'), m['rmse_m'], m['max_error_m']


def main():
    members = list(load_plant_family())
    _, default = load_control_profile(DEFAULT_PROFILE)
    with ProcessPoolExecutor(2) as pool:
        identified = dict(zip(members, pool.map(identified_gains, members)))
        jobs = [(mission, member, gains) for mission in MISSIONS for member in members
                for gains in (default, identified[member][0])]
        results = list(pool.map(fly, jobs))
    print('### Transfer: missions x plant family x profile (offline loop, 2 m/s)\n')
    print(__doc__.split('\n\n', 1)[1].strip().replace('\n', ' ') + '\n')
    print('Identified (figure8, default profile): attitude lag = tau + dead time of the FOPDT fit with its 95 % '
          'interval over 6 parts of the flight, thrust scale k = delivered / commanded specific force.\n')
    print('| member | roll lag (s) | pitch lag (s) | thrust scale |\n|---|---|---|---|')
    for member in members:
        r = identified[member][1]
        lag = ' | '.join(f'{r[a]["lag_s"]:.3f} ({r[a]["lag_ci95_s"][0]:.3f}-{r[a]["lag_ci95_s"][1]:.3f})'
                         for a in ('roll', 'pitch'))
        t = r['thrust']
        print(f'| {member} | {lag} | {t["thrust_scale"]:.4f} ({t["thrust_scale_ci95"][0]:.4f}-'
              f'{t["thrust_scale_ci95"][1]:.4f}) |')
    print('\n| mission | member | default: completed | default: RMSE / max (cm) | identified: completed '
          '| identified: RMSE / max (cm) |\n|---|---|---|---:|---|---:|')
    worst = {'default': 0.0, 'identified': 0.0}
    for i in range(0, len(jobs), 2):
        mission, member, _ = jobs[i]
        cells = []
        for name, (ok, rmse, peak) in zip(('default', 'identified'), results[i:i + 2]):
            worst[name] = max(worst[name], rmse if ok else float('inf'))
            cells += ['yes' if ok else '**no**', f'{100 * rmse:.2f} / {100 * peak:.2f}']
        print(f'| {mission} | {member} | {" | ".join(cells)} |')
    print(f'\nWorst RMSE: default {100 * worst["default"]:.2f} cm (goal < 5), identified '
          f'{100 * worst["identified"]:.2f} cm (goal < 2).\n')
    identified_peer, rows = rotorpy_rows()
    print('Independent plant: rotorpy 3.0.0 `Multirotor` with its Crazyflie parameters (72 ms motors, its own SO(3) '
          'PD attitude loop kp 310 / kd 57 on `cmd_ctatt`, rotor drag on), in its own venv (bench/peers.py), flown by '
          'our planner and position controller (the pure cores) at 100 Hz; identified from its figure8 flight '
          'with the default profile.\n')
    if not rows:
        print(f'rotorpy: not measured ({identified_peer})')
        return
    r = identified_peer
    print(f'rotorpy identified: roll lag {r["roll"]["lag_s"]:.3f} s ({r["roll"]["lag_ci95_s"][0]:.3f}-'
          f'{r["roll"]["lag_ci95_s"][1]:.3f}), pitch lag {r["pitch"]["lag_s"]:.3f} s, thrust scale '
          f'{r["thrust_scale"]:.4f}.\n')
    print('| mission | default: completed | default: RMSE / max (cm) | identified: completed | identified: RMSE / max '
          '(cm) |\n|---|---|---:|---|---:|')
    for mission, a, b in rows:
        print(f'| {mission} | ' + ' | '.join(f'{"yes" if m["completed"] else "**no**"} | {100 * m["rmse_m"]:.2f} / '
                                               f'{100 * m["max_error_m"]:.2f}' for m in (a, b)) + ' |')


if __name__ == '__main__':
    main()
