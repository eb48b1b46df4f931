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
sys.path[:0] = [str(p) for p in sorted((ROOT / 'src').glob('quad_*'))]

from quad_bringup.closed_loop import LoopOptions, fly_offline, load_control_profile  # noqa: E402
from quad_bringup.identify import identify  # noqa: E402
from quad_bringup.report import load_flight  # noqa: E402
from quad_common.vehicle import load_plant_family  # noqa: E402
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
          f'{100 * worst["identified"]:.2f} cm (goal < 2).')


if __name__ == '__main__':
    main()
