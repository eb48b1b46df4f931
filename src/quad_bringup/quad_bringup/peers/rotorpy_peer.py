"""rotorpy 3.0.0, a peer library, as a plant and a controller we did not write, from its own venv
(quad_bringup.peers.peer_venv): its Multirotor flown by our position controller and recorded as the graph records a
flight (rotorpy_log, rotorpy_bag, rotorpy_mission_bag), its hold at a scaled attitude lag (rotorpy_hold), and its
installed package linked alone into a directory for PYTHONPATH (rotorpy_dir), as a user's `pip install rotorpy` would
make its SE3Control importable (SE3CONTROL). Not part of a flight: shared by the tests that check identify and the
plugin path against it and by the transfer and plugin benches."""

import json
import subprocess
import tempfile
from pathlib import Path

import numpy as np

import quad_common
import quad_control
from quad_bringup.peers.peer_venv import peer_python, run_peer
from quad_common.paths import resolve_config
from quad_common.yaml_io import load_yaml
from quad_trajectory.mission import load_mission, plan_mission

SE3CONTROL = 'rotorpy.controllers.quadrotor_control:SE3Control'
MISSION_SPEED_MPS = 2.0   # rotorpy_mission_bag's average speed: the transfer bench's

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
    npz, out = Path(tmp) / f'{name}.npz', Path(tmp) / f'{name}-log.npy'
    np.savez(npz, t=trajectory.times_s, p=trajectory.position, v=trajectory.velocity, a=trajectory.acceleration)
    paths = [str(Path(package.__file__).resolve().parent.parent) for package in (quad_common, quad_control)]
    vehicle = load_yaml(resolve_config('config/vehicles/crazyflie.yaml'))
    run_peer(ROTORPY_LOOP.format(paths=paths, npz=str(npz), out=str(out), vehicle=json.dumps(vehicle),
                                 controller=gains_values.get('controller', 'se3'), gains=json.dumps(gains_values),
                                 offset=[float(x) for x in offset_m], settle_s=float(settle_s),
                                 params=json.dumps(params or {})),
             timeout_s=600)
    return np.load(out)


def rotorpy_bag(log, bag_dir, trajectory=None):
    """The rotorpy flight written as the graph records one (quad_bringup.offline.closed_loop.FlightBag: odom and
    cmd/attitude_thrust, stamped in sim time; the plan `trajectory` from t = 0 when given): a real rosbag2 bag that
    `quadflight identify` and `replay` read."""
    from quad_bringup.offline.closed_loop import FlightBag
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
    from scipy.spatial.transform import Rotation

    from quad_bringup.offline.stability import HOLD_ALTITUDE_M, hold_of
    from quad_common.sampled_trajectory import SampledTrajectory
    t = np.arange(0.0, 20.0, 0.01)
    point = np.zeros((len(t), 4))
    point[:, 2] = HOLD_ALTITUDE_M
    still = np.zeros((len(t), 4))
    log = rotorpy_log(SampledTrajectory(t, point, still, still), gains_values, tmp, name, offset_m=(0.5, 0.0, 0.3),
                      settle_s=0.0, params={'kp_att': 310.0 / lag_factor ** 2, 'kd_att': 57.0 / lag_factor})
    euler = Rotation.from_quat(log[:, 7:11]).as_euler('ZYX')[:, :0:-1]   # (roll, pitch)
    return hold_of(lag_factor * ROTORPY_LAG_S, 0.0, 0.0, log[:, 1:4], euler, point[0, :3], 0.01)


def rotorpy_mission_bag(mission, gains_values, tmp, speed_mps: float = MISSION_SPEED_MPS):
    """(bag, plan, sampled trajectory): our planner + position controller flying rotorpy 3.0.0's Multirotor
    (Crazyflie parameters: its own 72 ms motors and SO(3) PD attitude loop, kp 310 / kd 57, its rotor drag) along
    `mission`'s plan (config/missions/MISSION.yaml) at speed_mps, recorded as a rosbag2 bag (rotorpy_bag) under tmp."""
    loaded = load_mission(resolve_config(f'config/missions/{mission}.yaml'))
    overrides = {'time_allocation': 'limits'} if loaded.options.v_max_mps is not None else {}
    plan = plan_mission(loaded, speed_mps=speed_mps, **overrides)
    trajectory = plan.trajectory.to_sampled(100.0)
    where = Path(tempfile.mkdtemp(prefix=f'{mission}-', dir=tmp))   # one flight each, however often flown
    bag = rotorpy_bag(rotorpy_log(trajectory, gains_values, where, mission), where / 'bag', trajectory)
    return bag, plan, trajectory


def rotorpy_dir(tmp: Path) -> Path:
    """A directory with only the peers' installed rotorpy package in it (and cvxopt, which its MinSnap imports), for
    PYTHONPATH."""
    site = Path(subprocess.run([peer_python(), '-c', 'import rotorpy, os; print(os.path.dirname(rotorpy.__path__[0]))'],
                               capture_output=True, text=True, check=True).stdout.strip())
    for name in ('rotorpy', 'cvxopt', 'cvxopt.libs'):
        if (site / name).exists():
            (tmp / name).symlink_to(site / name)
    return tmp
