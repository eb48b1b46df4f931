"""Fleets offline (quad_bringup.offline.fleet_loop): real-time factor of the lockstep fleet step at 1, 4, 16 and
64 vehicles, and the physics step as a loop over compiled Simulators beside a numpy core vectorized over vehicles."""

import os
import sys
import time

import numpy as np

from quad_bringup.offline.fleet_loop import fly_fleet
from quad_common.compiled import COMPILED
from quad_common.types import GRAVITY_MPS2, AttitudeSetpoint
from quad_common.vehicle import load_vehicle
from quad_common.yaml_io import load_yaml
from quad_sim import rigid_body as rb
from quad_sim.simulator import Simulator
from quad_trajectory.fleet import fleet_from_dict, plan_fleet

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FORMATION = os.path.join(ROOT, 'config/missions/fleets/formation4.yaml')
VEHICLE = os.path.join(ROOT, 'config/vehicles/crazyflie.yaml')
SIZES = (1, 4, 16, 64)
SPACING_M = 0.5


def grid_fleet(n):
    """n vehicles in a square grid SPACING_M apart, on fleet_formation4's shared path."""
    data = load_yaml(FORMATION)
    side = int(np.ceil(np.sqrt(n)))
    data['vehicles'] = [{'name': f'cf{k + 1}', 'offset': [SPACING_M * (k % side), SPACING_M * (k // side), 0.0]}
                        for k in range(n)]
    return fleet_from_dict(data, FORMATION)


def derivative(x, w, p):
    """rigid_body.derivative_into (no drag, no force, no wind) for N vehicles at once: x (N, 17), w (N, 4)."""
    s = x[:, 13:17] * np.abs(x[:, 13:17])     # thrust from the rotor speed states
    qx, qy, qz, qw = x[:, 6], x[:, 7], x[:, 8], x[:, 9]
    pr, qr, rr = x[:, 10], x[:, 11], x[:, 12]
    fz = p[:, rb.K_ETA] * s.sum(axis=1) / p[:, rb.MASS]
    out = np.empty_like(x)
    out[:, 0:3] = x[:, 3:6]
    out[:, 3] = 2 * (qx * qz + qy * qw) * fz
    out[:, 4] = 2 * (qy * qz - qx * qw) * fz
    out[:, 5] = (1 - 2 * (qx * qx + qy * qy)) * fz - GRAVITY_MPS2
    out[:, 6] = 0.5 * (qw * pr + qy * rr - qz * qr)
    out[:, 7] = 0.5 * (qw * qr - qx * rr + qz * pr)
    out[:, 8] = 0.5 * (qw * rr + qx * qr - qy * pr)
    out[:, 9] = -0.5 * (qx * pr + qy * qr + qz * rr)
    ixx, iyy, izz = p[:, rb.IXX], p[:, rb.IYY], p[:, rb.IZZ]
    out[:, 10] = (np.einsum('ij,ij->i', p[:, rb.MOM_X:rb.MOM_X + 4], s) + (iyy - izz) * qr * rr) / ixx
    out[:, 11] = (np.einsum('ij,ij->i', p[:, rb.MOM_Y:rb.MOM_Y + 4], s) + (izz - ixx) * rr * pr) / iyy
    out[:, 12] = (np.einsum('ij,ij->i', p[:, rb.MOM_Z:rb.MOM_Z + 4], s) + (ixx - iyy) * pr * qr) / izz
    out[:, 13:17] = (w - x[:, 13:17]) / p[:, rb.TAU:rb.TAU + 1]
    return out


def rk4(x, w, dt, p):
    k1 = derivative(x, w, p)
    k2 = derivative(x + 0.5 * dt * k1, w, p)
    k3 = derivative(x + 0.5 * dt * k2, w, p)
    k4 = derivative(x + dt * k3, w, p)
    x = x + dt / 6 * (k1 + 2 * (k2 + k3) + k4)
    x[:, 6:10] /= np.linalg.norm(x[:, 6:10], axis=1, keepdims=True)
    return x


def physics_per_tick_us(n, ticks=100):
    """(loop over Simulator.advance(10 ms), numpy RK4 over the fleet x 10 steps of 1 ms): wall us per 10 ms tick.
    The numpy core is the rigid body alone (no autopilot, mixer or events): a lower bound on a vectorized step."""
    vehicle = load_vehicle(VEHICLE)
    sims = [Simulator(vehicle, initial_position=(k, 0.0, 1.0)) for k in range(n)]
    sims[0].warm_up()
    sp = AttitudeSetpoint(quaternion=np.array([0.0, 0.02, 0.0, 1.0]) / np.linalg.norm([0.0, 0.02, 0.0, 1.0]))
    start = time.perf_counter()
    for _ in range(ticks):
        for sim in sims:
            sim.set_setpoint(sp)
            sim.advance(0.01)
    loop_us = (time.perf_counter() - start) / ticks * 1e6
    p = np.tile(sims[0].body.params, (n, 1))
    x = np.tile(np.array(sims[0]._x), (n, 1))
    w = np.tile(sims[0]._w_cmd, (n, 1))
    one = np.array(x[0])                                   # the numpy core is the compiled one's equations
    rb.rk4_step(one, w[0].copy(), 1e-3, rb.NO_FORCE, np.zeros(3), sims[0].body.params)
    assert np.allclose(rk4(x[:1], w[:1], 1e-3, p[:1])[0], one, rtol=1e-9, atol=1e-9)
    start = time.perf_counter()
    for _ in range(ticks):
        for _ in range(10):
            x = rk4(x, w, 1e-3, p)
    return loop_us, (time.perf_counter() - start) / ticks * 1e6


def main():
    rows = []
    for n in SIZES:
        fleet = grid_fleet(n)
        start = time.perf_counter()
        plan = plan_fleet(fleet)            # every vehicle planned, then the pairwise separation check
        plan_s = time.perf_counter() - start
        run = fly_fleet(fleet, fleet_plan=plan)
        ticks = len(run.t_s)
        done = sum(m['completed'] for m in run.metrics.values())
        rmse = max(m['rmse_m'] for m in run.metrics.values())
        loop_us, numpy_us = physics_per_tick_us(n)
        rows.append(f'| {n} | {run.sim_s:.2f} | {run.wall_s["total"]:.2f} | **{run.real_time_factor:.1f}x** | '
                    f'{run.wall_s["control"] / ticks * 1e6:.0f} | {run.wall_s["physics"] / ticks * 1e6:.0f} | '
                    f'{run.wall_s["collision"] / ticks * 1e6:.0f} | {done}/{n} | {rmse * 100:.2f} | '
                    f'{loop_us:.0f} | {numpy_us:.0f} | {plan_s:.2f} |')
        print(f'{n} vehicles: {run.real_time_factor:.1f}x', file=sys.stderr)
    print('## Fleets offline (bench_fleet)\n')
    print(f'`fly_fleet` (quad_bringup.offline.fleet_loop): N Crazyflies in a square grid {SPACING_M} m apart on '
          '`fleets/formation4.yaml`\'s path, each with its own ControlLoop (pd, 100 Hz) and Simulator (1 kHz physics, '
          f'{"compiled" if COMPILED else "interpreted"}), stepped in lockstep, pairwise collision check every tick. '
          'Real-time factor = simulated s / wall s of the whole flight. Per-tick wall time split into the controllers, '
          'the physics and the collision check. Two columns time the physics alone per 10 ms tick: the '
          'loop over compiled Simulators fly_fleet uses, and a numpy RK4 vectorized over the fleet (the rigid body '
          'only, no autopilot or mixer: a lower bound for a vectorized step). Last: `plan_fleet` (each vehicle '
          'planned, then every pair checked every ~5 ms of the flight).\n')
    print('| vehicles | simulated (s) | wall (s) | real-time factor | control (us/tick) | physics (us/tick) | '
          'collisions (us/tick) | completed | worst rmse (cm) | Simulator loop (us/tick) | numpy vectorized '
          '(us/tick) | plan + separation (s) |')
    print('|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|')
    print('\n'.join(rows))
    print('\nThe control loops (Python: the plan\'s reference, the controller, the loop\'s rules; ~60 us per vehicle '
          'per tick) cost the most. The compiled physics costs a few '
          'tens of us per vehicle per tick; the numpy core costs milliseconds per tick at any size (~40 array '
          'operations per RK4 stage, 40 stages per tick), more than the whole Simulator loop up to 64 vehicles, so '
          'fly_fleet loops over Simulators. Crazyswarm2\'s simulation (its own measurement, its machine): '
          '0.70x real time with 1 drone, 0.15x with 5, 0.05x with 16 (its machine, through ROS; this is not).')


if __name__ == '__main__':
    main()
