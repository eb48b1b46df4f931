"""The whole simulated vehicle: autopilot, failsafe, floor, world, validity checks, disturbances."""

import math
import os

import numpy as np
import pytest

from quad_common import rotations
from quad_common.compiled import compile_lock_path
from quad_common.types import GRAVITY_MPS2, AttitudeSetpoint
from quad_common.world import World
from quad_sim import simulator as simulator_module
from quad_sim.attitude_poles import attitude_damping, attitude_loop_poles, damping_ratio
from quad_sim.disturbances import load_profile, profile_from_dict
from quad_sim.simulator import SPEED_LIMIT, SimulationStopped, Simulator

CONFIG = os.path.join(os.path.dirname(__file__), '..', '..', '..', 'config')
HOVER = AttitudeSetpoint(specific_force_mps2=GRAVITY_MPS2)


def _fly(sim, setpoint, seconds, period_s=0.01):
    for _ in range(int(round(seconds / period_s))):
        sim.set_setpoint(setpoint)
        sim.advance(period_s)


def _kinds(sim, ignore=()):
    return [e.kind for e in sim.events if e.kind not in ignore]


@pytest.mark.parametrize('vehicle', ['crazyflie', 'px4_quad'])
def test_hover_speed_closed_form_and_stays_put(vehicle, request):
    v = request.getfixturevalue(vehicle)
    sim = Simulator(v, initial_position=(1, -2, 1.5), initial_yaw=0.7)
    _fly(sim, AttitudeSetpoint(quaternion=rotations.from_yaw(0.7), specific_force_mps2=GRAVITY_MPS2), 2.0)
    assert np.allclose(sim.rotor_speeds_radps, math.sqrt(v.mass_kg * GRAVITY_MPS2 / (4 * v.k_eta)), rtol=1e-9)
    assert np.allclose(sim.state.position, [1, -2, 1.5], atol=1e-9)
    assert sim.time_ns == 2_000_000_000 and sim.events == []
    assert np.allclose(sim.specific_force_body_mps2, [0, 0, GRAVITY_MPS2], atol=1e-9)


def test_a_held_vehicle_waits_where_it_starts_and_then_flies_without_a_failsafe(crazyflie):
    """hold_steps: time passes, the vehicle stays as it started (free, it sinks once the setpoint times out and
    lands by the failsafe); the first setpoint after the hold is flown, not a timed-out one."""
    sim = Simulator(crazyflie, initial_position=(0.0, 0.0, 1.0), setpoint_timeout_s=0.5)
    sim.hold_steps(sim.steps_in(3.0))
    assert sim.time_ns == 3_000_000_000 and np.array_equal(sim.state.position, [0.0, 0.0, 1.0])
    _fly(sim, HOVER, 1.0)
    assert sim.events == [] and abs(sim.state.position[2] - 1.0) < 1e-6
    free = Simulator(crazyflie, initial_position=(0.0, 0.0, 1.0), setpoint_timeout_s=0.5)
    free.advance(3.0)
    assert 'failsafe' in _kinds(free) and free.state.position[2] < 0.5


def test_shipped_vehicles_have_a_damped_attitude_loop(crazyflie, px4_quad):
    assert attitude_damping(crazyflie) >= 0.15 and attitude_damping(px4_quad) >= 0.15
    assert damping_ratio(attitude_loop_poles(3000, 300, 0.072)) < 0.05  # rotorpy's lag: barely damped


def test_tilt_setpoint_is_tracked_and_accelerates(crazyflie):
    sim = Simulator(crazyflie, initial_position=(0, 0, 1))
    tilt = AttitudeSetpoint(quaternion=rotations.from_euler(0.0, 0.1, 0.0),
                            specific_force_mps2=GRAVITY_MPS2 / math.cos(0.1))
    _fly(sim, tilt, 1.0)
    assert rotations.to_euler(sim.state.quaternion)[1] == pytest.approx(0.1, abs=2e-3)
    assert sim.state.velocity[0] > 0.5 and abs(sim.state.position[2] - 1) < 0.05


def test_failsafe_levels_descends_lands_and_disarms(crazyflie):
    sim = Simulator(crazyflie, initial_position=(0.5, 0, 2.0), setpoint_timeout_s=0.5)
    sim.set_setpoint(AttitudeSetpoint(quaternion=rotations.from_euler(0.05, 0, 0.3), specific_force_mps2=9.9))
    sim.advance(0.4)
    assert not sim.failsafe_active
    sim.advance(0.2)
    assert sim.failsafe_active and _kinds(sim, ignore='saturation') == ['failsafe']  # the yaw step saturates
    assert sim.events[-1].time_s == pytest.approx(0.501, abs=1e-9)
    sim.advance(2.0)
    assert sim.state.velocity[2] == pytest.approx(-0.5, abs=0.05)
    sim.advance(6.0)
    assert sim.landed and not sim.armed and sim.state.position[2] == 0.0
    assert _kinds(sim, ignore='saturation') == ['failsafe', 'touchdown', 'disarmed']
    touchdown = [e for e in sim.events if e.kind == 'touchdown'][0]
    assert abs(touchdown.detail['vertical_speed_mps']) < 0.6
    assert abs(rotations.to_euler(sim.state.quaternion)[2] - 0.3) < 0.05  # kept its yaw
    sim.set_setpoint(HOVER)
    assert not sim.failsafe_active and sim.armed and _kinds(sim)[-1] == 'failsafe_cleared'


def test_rests_on_and_takes_off_from_the_floor(crazyflie):
    sim = Simulator(crazyflie, initial_position=(0, 0, 0))
    assert sim.landed
    _fly(sim, AttitudeSetpoint(specific_force_mps2=0.8 * GRAVITY_MPS2), 1.0)
    assert sim.state.position[2] == 0.0 and np.all(sim.state.velocity == 0)
    assert np.allclose(sim.specific_force_body_mps2, [0, 0, GRAVITY_MPS2])
    _fly(sim, AttitudeSetpoint(specific_force_mps2=1.3 * GRAVITY_MPS2), 0.5)
    assert sim.state.position[2] > 0.1 and _kinds(sim) == ['takeoff']
    lowest = np.inf
    for _ in range(200):  # cut the thrust: falls back, never below the floor
        sim.set_setpoint(AttitudeSetpoint(specific_force_mps2=0.0))
        sim.advance(0.01)
        lowest = min(lowest, sim.state.position[2])
    assert lowest == 0.0 and sim.landed and _kinds(sim) == ['takeoff', 'saturation', 'touchdown']


def test_collision_reported_with_time_and_place(crazyflie):
    world = World([-5, 5, -5, 5, 0, 4], [[1.0, 2.0, -1.0, 1.0, 0.0, 3.0]])
    sim = Simulator(crazyflie, initial_position=(0, 0, 1), world=world, robot_radius_m=0.1)
    assert sim.floor_z_m == 0.0
    forward = AttitudeSetpoint(quaternion=rotations.from_euler(0, 0.15, 0), specific_force_mps2=GRAVITY_MPS2 / 0.99)
    _fly(sim, forward, 1.5)
    collisions = [e for e in sim.events if e.kind == 'collision']
    assert sim.collided and len(collisions) == 1
    hit = collisions[0]
    assert hit.position[0] == pytest.approx(0.9, abs=0.01) and 0 < hit.time_s < 1.5
    assert hit.detail['clearance_m'] <= 0.1


def test_validity_stop_names_its_reason(crazyflie):
    sim = Simulator(crazyflie, initial_position=(0, 0, 50), max_speed_mps=3.0)
    with pytest.raises(SimulationStopped) as stop:
        _fly(sim, AttitudeSetpoint(specific_force_mps2=0.0), 2.0)
    assert stop.value.reason == SPEED_LIMIT and 'speed' in str(stop.value)
    assert stop.value.time_s == pytest.approx(3.0 / GRAVITY_MPS2, abs=0.02)
    with pytest.raises(SimulationStopped):
        sim.advance(0.01)
    with pytest.raises(ValueError, match='setpoint must be finite'):
        sim.set_setpoint(AttitudeSetpoint(specific_force_mps2=float('nan')))
    sim2 = Simulator(crazyflie, initial_position=(0, 0, 1))
    with pytest.raises(SimulationStopped, match='far_from_reference'):
        sim2.check_tracking([3.0, 0, 1], max_error_m=2.0)


@pytest.mark.parametrize('kwargs,words', [
    (dict(physics_rate_hz=0.0), 'physics_rate_hz = 0.0'), (dict(initial_position=(0, 0, -1)), 'below the floor'),
    (dict(setpoint_timeout_s=-1.0), 'setpoint_timeout_s = -1.0'), (dict(initial_yaw=math.inf), 'initial_yaw'),
])
def test_bad_arguments_refused(crazyflie, kwargs, words):
    with pytest.raises(ValueError, match=words):
        Simulator(crazyflie, **kwargs)


def test_advance_refuses_partial_steps_and_keeps_integer_time(crazyflie):
    sim = Simulator(crazyflie, physics_rate_hz=500.0, initial_position=(0, 0, 1))
    with pytest.raises(ValueError, match='whole number of physics steps'):
        sim.advance(0.003)
    for _ in range(1000):
        sim.set_setpoint(HOVER)
        sim.advance(0.01)
    assert sim.time_ns == 10_000_000_000


def test_reset_restores_the_start(crazyflie):
    sim = Simulator(crazyflie, initial_position=(0, 0, 1))
    _fly(sim, AttitudeSetpoint(quaternion=rotations.from_euler(0.1, 0, 0)), 0.5)
    sim.reset()
    assert sim.time_ns == 0 and sim.events == [] and np.allclose(sim.state.position, [0, 0, 1])


def test_wind_and_drag_push_downwind(crazyflie):
    profile = load_profile(os.path.join(CONFIG, 'disturbances.yaml'), 'drag_wind')
    runs = []
    for seed in (1, 1, 2):
        sim = Simulator(crazyflie, initial_position=(0, 0, 1), disturbances=profile, seed=seed)
        _fly(sim, HOVER, 2.0)
        runs.append(sim.state.position)
    assert runs[0][0] > 0.05  # drifts with the +x wind
    assert np.array_equal(runs[0], runs[1]) and not np.array_equal(runs[0], runs[2])


def test_odometry_noise_seeded_and_latency(crazyflie):
    profile = profile_from_dict({'odom_noise': {'position_std_m': 0.01}, 'odom_latency_s': 0.02}, 'test')
    a, b = (Simulator(crazyflie, initial_position=(0, 0, 1), disturbances=profile, seed=7) for _ in range(2))
    tilt = AttitudeSetpoint(quaternion=rotations.from_euler(0, 0.2, 0), specific_force_mps2=10.0)
    truth = []
    for sim in (a, b):
        for _ in range(30):
            sim.set_setpoint(tilt)
            sim.advance(0.01)
            truth.append(sim.state.velocity[0])
    va, vb = a.odometry_state(), b.odometry_state()
    assert np.array_equal(va.position, vb.position) and 0 < abs(va.position[1]) < 0.05
    assert va.velocity[0] == pytest.approx(truth[27], abs=1e-12)  # 20 ms old


def test_unknown_profile_named():
    with pytest.raises(ValueError, match="disturbances = 'gale'"):
        load_profile(os.path.join(CONFIG, 'disturbances.yaml'), 'gale')
    with pytest.raises(ValueError, match='wind_mps'):
        profile_from_dict({'wind_mps': [1, 2]}, 'p')


def test_quiet_step_runs_equal_step_by_step_physics(crazyflie, monkeypatch):
    """advance() runs uneventful steps in one compiled call; stepping one at a time gives the same bits,
    through saturation, a collision, the failsafe and a landing. The compiled path must really have run most of
    the steps (else this compares the step-by-step path with itself: a quiet_steps that does nothing passes)."""
    world = World([-5, 5, -5, 5, 0, 4], [[1.0, 2.0, -1.0, 1.0, 0.0, 3.0]])
    quiet = simulator_module.quiet_steps
    quiet_done = []

    def counted_quiet_steps(*args):
        done = quiet(*args)
        quiet_done.append(done)
        return done

    monkeypatch.setattr(simulator_module, 'quiet_steps', counted_quiet_steps)
    runs = []
    for one_at_a_time in (False, True):
        sim = Simulator(crazyflie, initial_position=(0, 0, 1), world=world, setpoint_timeout_s=0.3)
        for k in range(220):
            if k < 160:
                sim.set_setpoint(AttitudeSetpoint(quaternion=rotations.from_euler(0.0, 0.15, 0.01 * k),
                                                  specific_force_mps2=GRAVITY_MPS2 * (1.01 if k % 7 else 1.6)))
            if one_at_a_time:
                for _ in range(sim.steps_in(0.01)):
                    sim._physics_step()
            else:
                sim.advance(0.01)
        runs.append((sim.state, sim.rotor_speeds_radps, [(e.kind, e.time_s) for e in sim.events], sim.time_ns))
    (a, wa, ea, ta), (b, wb, eb, tb) = runs
    steps = 220 * Simulator(crazyflie).steps_in(0.01)
    assert sum(quiet_done) > steps // 2, f'the compiled path ran {sum(quiet_done)} of {steps} steps'
    assert {'saturation', 'collision', 'failsafe'} <= {kind for kind, _ in ea}
    assert ea == eb and ta == tb and np.array_equal(wa, wb)
    for name in ('position', 'velocity', 'quaternion', 'body_rates'):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


def test_failsafe_brakes_and_lands_where_the_setpoints_stopped(crazyflie):
    """PX4's and ArduPilot's setpoint-loss landing hold position while descending; a failsafe that only levels
    drifted 2.4 m from a 0.5 m/s flight. From 2 m/s it must come down within 0.5 m of the position at
    the last setpoint."""
    sim = Simulator(crazyflie, initial_position=(0.0, 0.0, 1.5), setpoint_timeout_s=0.5)
    sim._x[3:5] = (2.0 / math.sqrt(2), 2.0 / math.sqrt(2))   # a 2 m/s flight along (1, 1), level
    sim.set_setpoint(HOVER)                                    # the last setpoint: here, at (0, 0)
    sim.advance(15.0)
    assert sim.landed and not sim.armed
    kinds = _kinds(sim, ignore='saturation')
    assert kinds[:1] == ['failsafe'] and 'disarmed' in kinds
    touchdown = [e for e in sim.events if e.kind == 'touchdown'][0]
    assert math.hypot(*touchdown.position[:2]) < 0.5
    assert math.hypot(*sim.state.position[:2]) < 0.5


def test_loading_the_kernels_imports_no_scipy_linalg():
    """The simulator's start (its import and warm_up, which loads or compiles the kernels) does not import
    scipy.linalg: numba would import it only to check for a BLAS that no kernel calls (quad_common.compiled)."""
    import subprocess
    import sys

    script = ('import sys; from quad_common.vehicle import load_vehicle; from quad_sim.simulator import Simulator; '
              f'Simulator(load_vehicle({os.path.join(CONFIG, "vehicles", "crazyflie.yaml")!r})).warm_up(); '
              'print(sorted(m for m in sys.modules if m.startswith("scipy.linalg")))')
    out = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True, timeout=600, check=True)
    assert out.stdout.strip() == '[]', out.stdout


def _blocked_on_a_lock(pid: int) -> bool:
    """Whether process pid waits for a file lock (/proc/locks lists a waiter as '-> FLOCK ...')."""
    with open('/proc/locks') as locks:
        return any('->' in line and f' {pid} ' in line for line in locks)


def test_warm_up_waits_while_another_process_loads_or_compiles_the_kernels(crazyflie, tmp_path):
    """Processes started together on a cache without their kernels compile them one at a time
    (quad_common.compiled.one_compiler): a warm_up waits while another process holds the lock of its source folder's
    kernels, then goes on (here it loads a copy of this process's cache)."""
    import fcntl
    import shutil
    import subprocess
    import sys
    import time

    Simulator(crazyflie).warm_up()   # this process's kernels, in its cache: the copy below holds them
    cache = tmp_path / 'cache'
    shutil.copytree(os.environ['NUMBA_CACHE_DIR'], cache, ignore=shutil.ignore_patterns('compile-*.lock'))
    script = ('from quad_common.vehicle import load_vehicle; from quad_sim.simulator import Simulator; '
              f'Simulator(load_vehicle({os.path.join(CONFIG, "vehicles", "crazyflie.yaml")!r})).warm_up(); '
              'print("warm")')
    with open(compile_lock_path(str(cache), os.path.dirname(simulator_module.__file__)), 'a') as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        child = subprocess.Popen([sys.executable, '-c', script], env=dict(os.environ, NUMBA_CACHE_DIR=str(cache)),
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + 300
            while not _blocked_on_a_lock(child.pid) and child.poll() is None and time.monotonic() < deadline:
                time.sleep(0.01)   # polling /proc/locks: the child's start (its imports) takes a while
            assert child.poll() is None and _blocked_on_a_lock(child.pid), \
                'warm_up did not wait for the lock held by another process'
        except BaseException:
            child.kill()
            child.communicate()
            raise
        finally:
            held.close()   # released: the child goes on
    out, err = child.communicate(timeout=600)
    assert child.returncode == 0 and out.strip() == 'warm', err
