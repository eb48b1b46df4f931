"""Flight quality that transfers: every mission x plant family member x profile, in the offline loop.

The plant family (config/plant_family.yaml) stands for vehicles we did not tune on: slow motors, an autopilot's
own attitude loop (a PX4-like SO(3) cascade, an ArduPilot-like lagged target), a heavier vehicle, a wrong hover
thrust. Profiles: `default` is what `quadflight fly --controller se3` flies (config/control_se3.yaml);
`identified` is what
`quadflight identify --base config/control_se3.yaml --vehicle <the mission's>` gives from a bag of one figure8
flight of the same member with the default profile (its function, check_bag, with its quality gates and margin
check): the profile it writes, or the default where it refuses (nothing written). Each flight: 2 m/s average,
the mission's limits-aware allocation where the mission gives trajectory.limits (figure8, long_100),
quad_bringup.offline.closed_loop (the graph's pieces and timing without DDS; RMSE and completion as `quadflight report`
computes them). Goal: default never diverges, completes, RMSE < 5 cm; identified RMSE < 2 cm.
"""

import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(p) for p in sorted((ROOT / 'src').glob('quad_*'))]

from quad_bringup.commands.identify import check_bag  # noqa: E402
from quad_bringup.offline.closed_loop import LoopOptions, control_profile, fly_offline, load_control_profile  # noqa: E402
from quad_bringup.peers.rotorpy_peer import MISSION_SPEED_MPS, rotorpy_mission_bag  # noqa: E402
from quad_common.vehicle_file import load_plant_family  # noqa: E402
from quad_common.yaml_io import load_yaml  # noqa: E402
from quad_control.parameters import profile_parameters  # noqa: E402
from quad_trajectory.mission import load_mission  # noqa: E402

MISSIONS = ('maze', 'window', 'figure8', 'long_100')
SPEED_MPS = MISSION_SPEED_MPS   # rotorpy's flights fly the same
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


def rotorpy_flight(mission, gains_values, tmp):
    """rotorpy_mission_bag's flight read back as `quadflight report` reads a bag: a Flight."""
    from quad_bringup.analysis.report import load_flight
    bag, plan, trajectory = rotorpy_mission_bag(mission, gains_values, tmp, SPEED_MPS)
    flight = load_flight(bag)
    flight.traj_start_s, flight.trajectory, flight.waypoints = 0.0, trajectory, plan.waypoints
    return flight


def rotorpy_rows():
    """(identification, its refusal or None, [(mission, default metrics, identified metrics)]) on rotorpy's
    plant through `quadflight identify`'s check_bag (--vehicle crazyflie.yaml), or the reason it is missing (the
    peer is optional)."""
    from quad_bringup.analysis.report import compute_metrics
    from quad_common.paths import resolve_config
    try:
        values = profile_parameters(load_yaml(resolve_config(DEFAULT_PROFILE)))
        with tempfile.TemporaryDirectory(prefix='bench_transfer-rotorpy-') as tmp:
            bag, _, _ = rotorpy_mission_bag(IDENTIFY_MISSION, values, tmp, SPEED_MPS)
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
          'PD attitude loop kp 310 / kd 57 on `cmd_ctatt`, rotor drag on), in its own venv '
          '(quad_bringup.peers.peer_venv), '
          'flown by our planner and position controller (the pure cores) at 100 Hz; identified from its figure8 flight '
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
