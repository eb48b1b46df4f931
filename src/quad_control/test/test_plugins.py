"""User controllers (quad_control.plugins): names resolved, the flightsim / rotorpy adapter's conversions, and user
code that fails (raise, NaN, slow, wrong keys or shapes, motor speeds only, a broken constructor) never giving a
setpoint again."""

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from quad_common import rotations
from quad_common.params import check_value
from quad_common.paths import resolve_config
from quad_common.ros.testing import isolated_domain
from quad_common.types import GRAVITY_MPS2, AttitudeSetpoint, Reference, State
from quad_common.vehicle import load_vehicle
from quad_control import plugins
from quad_control.loop import ControlLoop
from quad_control.parameters import SPECS
from quad_control.plugins import ControllerRefused, make_controller
from quad_control.position import Limits, PositionController, PositionGains

VEHICLE = load_vehicle(resolve_config('config/vehicles/crazyflie.yaml'))
HERE = Path(__file__).resolve().parent
FLIGHTSIM = 'quad_control.templates.flightsim_controller:SE3Control'
OURS = 'quad_control.templates.my_controller:MyController'
CONTROLLER_SPEC = next(s for s in SPECS if s.name == 'controller')


def _hover_state(z=1.0):
    return State(position=np.array([0.0, 0.0, z]))


def _loop(name, wall_clock=False, rate_hz=100.0):
    """wall_clock: a real-time loop (a real vehicle's), on a busy machine only with a long tick (rate_hz)."""
    faults = []
    loop = ControlLoop(make_controller(name, None, VEHICLE, Limits.of(VEHICLE), rate_hz, wall_clock=wall_clock),
                       rate_hz, on_fault=faults.append)
    return loop, faults


def _fly_until_dead(loop, ticks=200):
    """Ticks (10 ms) at a hover until the controller dies; the number of setpoints it gave."""
    given = 0
    for k in range(ticks):
        tick = loop.control(k * 10_000_000, _hover_state())
        if tick is None:
            break
        assert tick.setpoint.is_finite()
        given += 1
    return given


def test_names_resolve_to_ours_or_the_user_class():
    assert isinstance(make_controller('se3', None, VEHICLE), PositionController)
    flightsim = make_controller(FLIGHTSIM, None, VEHICLE)
    ours = make_controller(OURS, None, VEHICLE)
    assert not flightsim.ours and ours.ours and flightsim.name == FLIGHTSIM


@pytest.mark.parametrize('name, reason', [
    ('lqr', "controller = 'lqr' refused: must be one of pd, pid, se3"),
    ('no_such_module:Thing', "importing 'no_such_module' failed: ModuleNotFoundError"),
    ('quad_control.templates.my_controller:Nope', "module 'quad_control.templates.my_controller' has no 'Nope'"),
    ('quad_control.templates.my_controller:np', 'is not a class with an update method'),
])
def test_a_name_that_does_not_resolve_is_refused_by_the_parameter_check(name, reason):
    refused = check_value(CONTROLLER_SPEC, name)
    assert refused is not None and reason in refused, refused
    with pytest.raises(ControllerRefused, match=reason.split(':')[0]):
        make_controller(name, None, VEHICLE)


def test_an_entry_point_of_an_installed_package_is_a_controller_name(tmp_path, monkeypatch):
    """A package registering `[quadflight.controllers] mine = pkg.mod:Class` (its dist-info on the path)."""
    (tmp_path / 'mine_pkg.py').write_text('from quad_control.templates.flightsim_controller import SE3Control\n')
    info = tmp_path / 'mine_pkg-1.0.dist-info'
    info.mkdir()
    (info / 'METADATA').write_text('Metadata-Version: 2.1\nName: mine-pkg\nVersion: 1.0\n')
    (info / 'entry_points.txt').write_text('[quadflight.controllers]\nmine = mine_pkg:SE3Control\n')
    monkeypatch.syspath_prepend(str(tmp_path))
    assert check_value(CONTROLLER_SPEC, 'mine') is None
    assert make_controller('mine', None, VEHICLE).cls.__name__ == 'SE3Control'
    assert 'mine' in check_value(CONTROLLER_SPEC, 'yours')   # the refusal lists what is installed


def test_vehicle_params_are_rotorpy_s_names_and_build_its_style_of_controller():
    params = plugins.vehicle_params(VEHICLE)
    assert params['mass'] == 0.030 and params['Ixx'] == 1.43e-5 and params['k_eta'] == params['k_thrust'] == 2.3e-8
    assert params['rotor_speed_max'] == 2500.0 and params['arm_length'] == 0.046
    # the yaw moment of rotor i is +rotor_directions[i] k_m w^2 in rotorpy, -spin[i] k_m w^2 here
    assert np.array_equal(params['rotor_directions'], -VEHICLE.rotor_geometry()[1])
    assert np.allclose(np.linalg.norm(np.array(list(params['rotor_pos'].values())), axis=1), 0.046)


def test_the_adapter_converts_state_and_reference_and_flies_cmd_thrust_and_cmd_q():
    """Hovering, the flightsim SE3 asks for m g along the yaw the plan gives; a lateral error tilts toward it."""
    control = make_controller(FLIGHTSIM, None, VEHICLE)
    setpoint, sat = control.update(_hover_state(), Reference(position=np.array([0.0, 0.0, 1.0]), yaw=0.3), 0.01)
    assert setpoint.specific_force_mps2 == pytest.approx(GRAVITY_MPS2)
    assert np.allclose(rotations.to_euler(setpoint.quaternion), [0.0, 0.0, 0.3])
    assert setpoint.body_rates is None and not sat.any
    ahead, _ = control.update(_hover_state(), Reference(position=np.array([0.1, 0.0, 1.0])), 0.01)
    assert rotations.to_matrix(ahead.quaternion)[0, 2] > 0.01   # body z leans toward +x (ENU, FLU)
    seen = {}

    class Spy:
        def __init__(self, quad_params):
            pass

        def update(self, t, state, flat_output):
            seen.update(t=t, state=state, flat=flat_output)
            return {'cmd_thrust': 0.3, 'cmd_q': np.array([0.0, 0.0, 0.0, 2.0])}

    spy = plugins.PluginController('spy', Spy, VEHICLE)
    q = rotations.from_euler(0.1, 0.0, 0.2)
    ref = Reference(position=np.array([1.0, 2, 3]), velocity=np.array([4.0, 5, 6]), acceleration=np.array([7.0, 8, 9]),
                    jerk=np.array([1.0, 1, 1]), yaw=0.5, yaw_rate=0.25)
    setpoint, _ = spy.update(State(position=np.array([1.0, 2, 3]), velocity=np.array([0.5, 0, 0]), quaternion=q,
                                   body_rates=np.array([0.1, 0.2, 0.3])), ref, 0.01)
    assert np.array_equal(seen['state']['q'], q) and np.array_equal(seen['state']['w'], [0.1, 0.2, 0.3])
    assert np.array_equal(seen['flat']['x_ddot'], [7, 8, 9]) and seen['flat']['yaw_dot'] == 0.25
    assert seen['t'] == pytest.approx(0.01)
    assert setpoint.specific_force_mps2 == pytest.approx(0.3 / 0.030)     # N -> thrust / mass
    assert np.array_equal(setpoint.quaternion, [0, 0, 0, 1])              # normalised


def test_our_interface_gets_position_controller_s_gains_before_every_update():
    """A control profile's (or tune's) kp reaches the template, also when changed after it was built."""
    control = make_controller(OURS, PositionGains(kp=np.array([1.0, 1.0, 1.0])), VEHICLE)
    off = _hover_state(0.9)
    soft, _ = control.update(off, Reference(position=np.array([0.0, 0.0, 1.0])), 0.01)
    control.gains = PositionGains(kp=np.array([10.0, 10.0, 10.0]))
    stiff, _ = control.update(off, Reference(position=np.array([0.0, 0.0, 1.0])), 0.01)
    assert control.instance.gains.kp[2] == 10.0
    assert stiff.specific_force_mps2 - GRAVITY_MPS2 == pytest.approx(10 * (soft.specific_force_mps2 - GRAVITY_MPS2))


def test_user_setpoints_are_clamped_to_the_vehicle_like_ours():
    class Wild:
        def __init__(self, quad_params):
            pass

        def update(self, t, state, flat_output):
            return {'cmd_thrust': 10.0, 'cmd_q': rotations.from_euler(1.2, 0.0, 0.4)}

    setpoint, sat = plugins.PluginController('wild', Wild, VEHICLE).update(_hover_state(), Reference(), 0.01)
    assert sat.thrust and sat.tilt
    assert setpoint.specific_force_mps2 * VEHICLE.mass_kg == pytest.approx(VEHICLE.thrust_max_n)
    body_z = rotations.to_matrix(setpoint.quaternion)[:, 2]
    assert math.degrees(math.acos(body_z[2])) == pytest.approx(VEHICLE.max_tilt_deg)
    assert rotations.to_euler(setpoint.quaternion)[2] == pytest.approx(0.4)   # heading kept


@pytest.mark.parametrize('cls, says', [
    ('Raises', "user_controllers.Raises.update raised ZeroDivisionError: division by zero in my controller ("),
    ('ReturnsNaN', 'returned a non-finite or zero setpoint: thrust/mass nan'),
    ('Slow', 'ms (3 updates in a row over the tick) > the tick 200.0 ms'),
    ('WrongKeys', "returned a dict without cmd_thrust and cmd_q (keys: ['q', 'thrust'])"),
    ('WrongShape', 'not a quaternion (x, y, z, w)'),
])
def test_a_failing_user_controller_is_dead_from_then_on(cls, says, monkeypatch):
    monkeypatch.syspath_prepend(str(HERE))
    # Slow sleeps 0.3 s: a tick of 0.2 s in real time (a busy machine's preemption must not count as slow)
    loop, faults = _loop(f'user_controllers:{cls}', wall_clock=cls == 'Slow', rate_hz=5.0 if cls == 'Slow' else 100.0)
    given = _fly_until_dead(loop)
    assert 45 <= given <= 52                       # it flew until t = 0.5 s, then nothing (never a bad setpoint)
    assert len(faults) == 1 and says in faults[0] and 'no setpoints from now on' in faults[0], faults
    assert str(HERE / 'user_controllers.py') in faults[0]     # the line: where it raised, or its update
    assert loop.counts['controller_failures'] == 1 and loop.mode(0) == 'controller dead (no setpoints)'
    assert all(loop.control(k * 10_000_000, _hover_state()) is None for k in range(60, 70))
    assert len(faults) == 1                        # reported once


def test_in_lockstep_only_cpu_time_counts_as_slow(monkeypatch):
    """A lockstep or offline flight waits for the controller: an update that waited (preempted on a busy machine,
    here a sleep) is no failure there; one that computes longer than the tick is (it cannot keep up)."""
    monkeypatch.syspath_prepend(str(HERE))
    loop, faults = _loop('user_controllers:Slow', wall_clock=False)
    assert _fly_until_dead(loop, ticks=55) == 55 and not faults
    loop, faults = _loop('user_controllers:Busy', wall_clock=False)
    assert 45 <= _fly_until_dead(loop) <= 52
    assert 'user_controllers.Busy.update took' in faults[0]
    assert 'ms of CPU (3 updates in a row over the tick) > the tick 10.0 ms' in faults[0]


def test_a_motor_level_controller_or_a_broken_constructor_is_refused_before_anything_starts(monkeypatch):
    monkeypatch.syspath_prepend(str(HERE))
    with pytest.raises(ControllerRefused, match="cmd_motor_speeds, cmd_moment without cmd_thrust and cmd_q: a "
                                                "motor-level controller cannot fly here, the attitude loop is the "
                                                "vehicle's"):
        make_controller('user_controllers:MotorOnly', None, VEHICLE)
    with pytest.raises(ControllerRefused, match=r"building user_controllers.BrokenInit failed: KeyError: "
                                                r"'no_such_key' \(.*user_controllers.py:\d+\)"):
        make_controller('user_controllers:BrokenInit', None, VEHICLE)


@pytest.mark.parametrize('bad, says', [
    ((0.0, 0.0), 'tuple, not an AttitudeSetpoint'),
    (AttitudeSetpoint(specific_force_mps2='9.81'), "an unusable result"),            # no check foresaw a string
    (AttitudeSetpoint(body_rates=np.zeros(2)), 'not three finite numbers'),
])
def test_our_interface_is_checked_alike(bad, says):
    class Bad(plugins.ControllerPlugin):
        def update(self, state, reference, dt_s):
            return AttitudeSetpoint(specific_force_mps2=GRAVITY_MPS2) if dt_s == 0.0 else bad

    loop = ControlLoop(plugins.PluginController('x', Bad, VEHICLE, wall_clock=False), 100.0)
    assert loop.control(0, _hover_state()) is not None
    assert loop.control(10_000_000, _hover_state()) is None and says in loop.dead, loop.dead


def test_the_node_refuses_an_unusable_controller_with_one_line_and_exit_2():
    env_path = f'{HERE}:' + ':'.join(sys.path)
    for name, says in (('user_controllers:MotorOnly', 'motor-level controller cannot fly here'),
                       ('no_such_module:X', "importing 'no_such_module' failed")):
        with isolated_domain() as (_, env):
            proc = subprocess.run([sys.executable, '-m', 'quad_control.position_controller_node', '--ros-args',
                                   '-p', f'controller:={name}'], env=dict(env, PYTHONPATH=env_path),
                                  capture_output=True, text=True, timeout=120)
        out = proc.stderr + proc.stdout
        assert proc.returncode == 2 and says in out and 'Traceback' not in out, out


def test_the_templates_hold_a_hover_in_the_loop():
    """Both templates, from 10 cm off, come back to the hold point in a first-order sense (not a flight test)."""
    for name in (OURS, FLIGHTSIM):
        control = make_controller(name, None, VEHICLE)
        setpoint, _ = control.update(_hover_state(0.9), Reference(position=np.array([0.0, 0.0, 1.0])), 0.01)
        assert setpoint.specific_force_mps2 > GRAVITY_MPS2, name     # climbs back
