"""Flight quality that transfers: every mission x plant family member x profile, in the offline loop.

The plant family (config/plant_family.yaml) stands for vehicles we did not tune on: slow motors, an autopilot's
own attitude loop (a PX4-like SO(3) cascade, an ArduPilot-like lagged target), a heavier vehicle, a wrong hover
thrust. Profiles: `default` is what `quadflight fly --controller se3` flies (config/control_se3.yaml);
`identified` is what
`quadflight identify --base config/control_se3.yaml --vehicle <the mission's>` gives from a bag of one figure8
flight of the same member with the default profile (its function, check_bag, with its quality gates and margin
check): the profile it writes, or the default where it refuses (nothing written). Each flight: 2 m/s average,
the mission's limits-aware allocation where the mission gives trajectory.limits (figure8, long_100),
quad_bringup.closed_loop (the graph's pieces and timing without DDS; RMSE and completion as `quadflight report`
computes them). Goal: default never diverges, completes, RMSE < 5 cm; identified RMSE < 2 cm.
"""

import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(p) for p in sorted((ROOT / 'src').glob('quad_*'))] + [str(ROOT / 'bench')]

from quad_bringup.closed_loop import LoopOptions, control_profile, fly_offline, load_control_profile  # noqa: E402
from quad_bringup.commands.identify import check_bag  # noqa: E402
from quad_common.vehicle import load_plant_family  # noqa: E402
from quad_common.yaml_io import load_yaml  # noqa: E402
from quad_control.parameters import profile_parameters  # noqa: E402
from quad_trajectory.mission import load_mission  # noqa: E402

MISSIONS = ('maze', 'window', 'figure8', 'long_100')
SPEED_MPS = 2.0
DEFAULT_PROFILE = 'config/control_se3.yaml'        # resolved under the checkout (quad_common.paths)
IDENTIFY_MISSION = 'figure8'


def _options(mission, member, gains, controller, **extra):
    path = ROOT / 'config' / 'missions' / f'{mission}.yaml'
    overrides = {'time_allocation': 'limits'} if load_mission(path).options.v_max_mps is not None else None
    return path, LoopOptions(controller=controller, gains=gains, speed_mps=SPEED_MPS, plan_overrides=overrides,
                             plant=member, **extra)


def identified_gains(member):
    """(gains `quadflight identify` gives for one family member: the profile it writes, or the default where it
    refuses; identification result; its refusal or None)."""
    controller, gains = load_control_profile(DEFAULT_PROFILE)
    with tempfile.TemporaryDirectory(prefix='bench_transfer-') as tmp:
        path, options = _options(IDENTIFY_MISSION, member, gains, controller, bag_dir=Path(tmp) / 'bag')
        fly_offline(path, options)
        checked = check_bag(Path(tmp) / 'bag', DEFAULT_PROFILE, load_mission(path).vehicle_path)
    if checked['refusal'] is None:
        _, gains = control_profile(checked['written'])
    return gains, checked['result'], checked['refusal']


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
quad_params = dict(quad_params, **json.loads({params!r}))
data = np.load({npz!r})
trajectory = SampledTrajectory(data['t'], data['p'], data['v'], data['a'])
vehicle = vehicle_from_dict(json.loads({vehicle!r}))
control = PositionController({controller!r}, gains_from(json.loads({gains!r})), vehicle, Limits.of(vehicle))
start = trajectory.position[0] + np.array([*{offset!r}, 0.0])
w0 = np.sqrt(quad_params['mass'] * 9.81 / (4 * quad_params['k_eta']))
state = {{'x': start[:3].copy(), 'v': np.zeros(3), 'q': Rotation.from_euler('z', start[3]).as_quat(), 'w': np.zeros(3),
         'wind': np.zeros(3), 'rotor_speeds': np.full(4, w0)}}
plant = Multirotor(quad_params, initial_state=state, control_abstraction='cmd_ctatt')
log = []
for k in range(int((trajectory.duration_s + {settle_s!r}) * 100)):
    t = k * 0.01
    seen = State(position=state['x'], velocity=state['v'], quaternion=state['q'], body_rates=state['w'])
    sp, _ = control.update(seen, trajectory.reference(min(t, trajectory.duration_s)), 0.01 if k else 0.0)
    rates = sp.body_rates if sp.body_rates is not None else np.full(3, np.nan)
    log.append([t, *state['x'], *state['v'], *state['q'], *state['w'], *state['rotor_speeds'],
                sp.specific_force_mps2, *sp.quaternion, *rates])
    state = plant.step(state, {{'cmd_thrust': sp.specific_force_mps2 * vehicle.mass_kg, 'cmd_q': sp.quaternion}}, 0.01)
    if not np.all(np.isfinite(state['x'])) or np.linalg.norm(state['x'] - start[:3]) > 1e3:
        break
np.save({out!r}, np.array(log))
'''
ROTORPY_TAU_M_S = 0.072          # rotorpy 3.0.0 crazyflie_params: motor time constant (reference for identify)
ROTORPY_LAG_S = 57.0 / 310.0     # its attitude PD kd / kp: the mean delay of kp / (s^2 + kd s + kp)
ROTORPY_ROTOR_DRAG = 10.2506e-07  # its k_d: body-frame horizontal drag k_d omega_i v per rotor (identify_drag's c)


def rotorpy_log(trajectory, gains_values, tmp, name, offset_m=(0.0, 0.0, 0.0), settle_s=3.0, params=None):
    """Our position controller (the pure core, 100 Hz, no latency) flying rotorpy 3.0.0's Multirotor along
    `trajectory` (a SampledTrajectory; started offset_m from its first point) in the peers' venv: one row per
    tick [t, x, v, q (xyzw), body rates, rotor speeds, commanded specific force, commanded q, commanded rates].
    params: rotorpy quad_params overrides (e.g. kd_att for another attitude lag)."""
    import json

    import numpy as np
    from peers import run_peer

    from quad_common.paths import resolve_config
    npz, out = Path(tmp) / f'{name}.npz', Path(tmp) / f'{name}-log.npy'
    np.savez(npz, t=trajectory.times_s, p=trajectory.position, v=trajectory.velocity, a=trajectory.acceleration)
    paths = [str(ROOT / 'src' / p) for p in ('quad_common', 'quad_control')]
    vehicle = load_yaml(resolve_config('config/vehicles/crazyflie.yaml'))
    run_peer(ROTORPY_LOOP.format(paths=paths, npz=str(npz), out=str(out), vehicle=json.dumps(vehicle),
                                 controller=gains_values.get('controller', 'se3'), gains=json.dumps(gains_values),
                                 offset=[float(x) for x in offset_m], settle_s=float(settle_s),
                                 params=json.dumps(params or {})),
             timeout_s=600)
    return np.load(out)


def rotorpy_bag(log, bag_dir, trajectory=None):
    """The rotorpy flight written as the graph records one (quad_bringup.closed_loop.FlightBag: odom and
    cmd/attitude_thrust, stamped in sim time; the plan `trajectory` from t = 0 when given): a real rosbag2 bag that
    `quadflight identify` and `replay` read."""
    import numpy as np

    from quad_bringup.closed_loop import FlightBag
    from quad_common.types import AttitudeSetpoint, State
    bag = FlightBag(bag_dir)
    if trajectory is not None:
        bag.write_trajectory(0.0, trajectory)
    for row in log:
        rates = row[23:26]
        bag.write(float(row[0]), State(position=row[1:4], velocity=row[4:7], quaternion=row[7:11],
                                       body_rates=row[11:14]),
                  AttitudeSetpoint(quaternion=row[19:23], specific_force_mps2=float(row[18]),
                                   body_rates=None if np.isnan(rates).any() else rates))
    bag.close()
    return Path(bag_dir)


def rotorpy_hold(gains_values, tmp, lag_factor=1.0, name='hold'):
    """stability.hold_on_autopilot's hold (20 s from a (0.5, 0, 0.3) m offset at HOLD_ALTITUDE_M) on rotorpy, its
    attitude response lag_factor times slower (kp_att / f^2, kd_att / f: the PD's poles scaled by 1 / f, lag
    f kd / kp): a stability.Hold."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    from quad_bringup.stability import HOLD_ALTITUDE_M, hold_of
    from quad_common.sampled_trajectory import SampledTrajectory
    t = np.arange(0.0, 20.0, 0.01)
    point = np.zeros((len(t), 4))
    point[:, 2] = HOLD_ALTITUDE_M
    still = np.zeros((len(t), 4))
    log = rotorpy_log(SampledTrajectory(t, point, still, still), gains_values, tmp, name, offset_m=(0.5, 0.0, 0.3),
                      settle_s=0.0, params={'kp_att': 310.0 / lag_factor ** 2, 'kd_att': 57.0 / lag_factor})
    euler = Rotation.from_quat(log[:, 7:11]).as_euler('ZYX')[:, :0:-1]   # (roll, pitch)
    return hold_of(lag_factor * ROTORPY_LAG_S, 0.0, 0.0, log[:, 1:4], euler, point[0, :3], 0.01)


def rotorpy_mission_bag(mission, gains_values, tmp):
    """(bag, plan, sampled trajectory): our planner + position controller flying rotorpy 3.0.0's Multirotor
    (Crazyflie parameters: its own 72 ms motors and SO(3) PD attitude loop, kp 310 / kd 57, its rotor drag) along
    `mission`'s plan at SPEED_MPS, recorded as a rosbag2 bag (rotorpy_bag) under tmp."""
    from quad_trajectory.mission import plan_mission
    loaded = load_mission(ROOT / 'config' / 'missions' / f'{mission}.yaml')
    overrides = {'time_allocation': 'limits'} if loaded.options.v_max_mps is not None else {}
    plan = plan_mission(loaded, speed_mps=SPEED_MPS, **overrides)
    trajectory = plan.trajectory.to_sampled(100.0)
    import tempfile
    where = Path(tempfile.mkdtemp(prefix=f'{mission}-', dir=tmp))   # one flight each, however often flown
    bag = rotorpy_bag(rotorpy_log(trajectory, gains_values, where, mission), where / 'bag', trajectory)
    return bag, plan, trajectory


def rotorpy_flight(mission, gains_values, tmp):
    """rotorpy_mission_bag's flight read back as `quadflight report` reads a bag: a Flight."""
    from quad_bringup.report import load_flight
    bag, plan, trajectory = rotorpy_mission_bag(mission, gains_values, tmp)
    flight = load_flight(bag)
    flight.traj_start_s, flight.trajectory, flight.waypoints = 0.0, trajectory, plan.waypoints
    return flight


def rotorpy_rows():
    """(identification, its refusal or None, [(mission, default metrics, identified metrics)]) on rotorpy's
    plant through `quadflight identify`'s check_bag (--vehicle crazyflie.yaml), or the reason it is missing (the
    peer is optional)."""
    from quad_bringup.report import compute_metrics
    from quad_common.paths import resolve_config
    try:
        values = profile_parameters(load_yaml(resolve_config(DEFAULT_PROFILE)))
        with tempfile.TemporaryDirectory(prefix='bench_transfer-rotorpy-') as tmp:
            bag, _, _ = rotorpy_mission_bag(IDENTIFY_MISSION, values, tmp)
            checked = check_bag(bag, DEFAULT_PROFILE, resolve_config('config/vehicles/crazyflie.yaml'))
            tuned = values if checked['refusal'] else profile_parameters(checked['written'])
            rows = [(m, compute_metrics(rotorpy_flight(m, values, tmp)), compute_metrics(rotorpy_flight(m, tuned, tmp)))
                    for m in MISSIONS]
        return checked['result'], checked['refusal'], rows
    except Exception as exc:  # noqa: BLE001 -- reported in the table instead
        return f'{type(exc).__name__}: {str(exc).splitlines()[-1] if str(exc) else ""}', None, []


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
    print('| member | roll lag (s) | pitch lag (s) | thrust scale | quadflight identify |\n|---|---|---|---|---|')
    for member in members:
        r, refusal = identified[member][1], identified[member][2]
        lag = ' | '.join(f'{r[a]["lag_s"]:.3f} ({r[a]["lag_ci95_s"][0]:.3f}-{r[a]["lag_ci95_s"][1]:.3f})'
                         for a in ('roll', 'pitch'))
        t = r['thrust']
        verdict = f'refused: {refusal.split(": fly ")[0]}' if refusal else 'written'
        print(f'| {member} | {lag} | {t["thrust_scale"]:.4f} ({t["thrust_scale_ci95"][0]:.4f}-'
              f'{t["thrust_scale_ci95"][1]:.4f}) | {verdict} |')
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
    identified_peer, peer_refusal, rows = rotorpy_rows()
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
          f'{r["thrust_scale"]:.4f}; quadflight identify (--vehicle crazyflie.yaml): '
          f'{"refused: " + peer_refusal if peer_refusal else "written"}.\n')
    print('| mission | default: completed | default: RMSE / max (cm) | identified: completed | identified: RMSE / max '
          '(cm) |\n|---|---|---:|---|---:|')
    for mission, a, b in rows:
        print(f'| {mission} | ' + ' | '.join(f'{"yes" if m["completed"] else "**no**"} | {100 * m["rmse_m"]:.2f} / '
                                               f'{100 * m["max_error_m"]:.2f}' for m in (a, b)) + ' |')


if __name__ == '__main__':
    main()
