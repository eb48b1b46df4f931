"""sim_node's parts without ROS: its vehicles from its parameters (quad_sim.parameters) and a vehicle's
diagnostics from its simulator's state (quad_sim.sim_diagnostics)."""

from types import SimpleNamespace

import numpy as np
import pytest

from quad_common import contract, diagnostics
from quad_sim.parameters import SPECS, fleet_layout
from quad_sim.sim_diagnostics import DIAGNOSTICS_PERIOD_S, ReportSchedule, vehicle_statuses
from quad_sim.simulator import Event
from quad_sim.vehicle_contact import VEHICLE_COLLISION

DEFAULTS = {spec.name: ([] if not isinstance(spec.default, (bool, int, float, str, list)) else spec.default)
            for spec in SPECS}


def _params(**values):
    return {**DEFAULTS, **values}


def test_one_vehicle_from_vehicle_and_initial_position():
    layout = fleet_layout(_params(vehicle='v.yaml', initial_position=[1.0, 2.0, 3.0], robot_radius_m=0.2))
    assert layout == [('', 'v.yaml', [1.0, 2.0, 3.0], 0.2)]


def test_fleet_takes_per_vehicle_arrays_and_defaults_the_rest():
    layout = fleet_layout(_params(vehicle='v.yaml', vehicle_names=['cf1', 'cf2'], robot_radius_m=0.15,
                                  initial_positions=[0.0, 0.0, 1.0, 1.0, 0.0, 1.0]))
    assert layout == [('cf1', 'v.yaml', [0.0, 0.0, 1.0], 0.15), ('cf2', 'v.yaml', [1.0, 0.0, 1.0], 0.15)]
    layout = fleet_layout(_params(vehicle_names=['a', 'b'], vehicle_files=['x.yaml', 'y.yaml'],
                                  initial_positions=[0.0] * 6, robot_radii_m=[0.1, 0.3]))
    assert [(f, r) for _, f, _, r in layout] == [('x.yaml', 0.1), ('y.yaml', 0.3)]


@pytest.mark.parametrize('values, message', [
    ({'vehicle_names': ['cf1', 'cf1'], 'initial_positions': [0.0] * 6}, "vehicle_names: 'cf1' refused: named twice"),
    ({'vehicle_names': ['cf-1'], 'initial_positions': [0.0] * 3}, "vehicle_names: 'cf-1' refused"),
    ({'vehicle_names': ['a', 'b'], 'initial_positions': [0.0] * 5}, 'initial_positions = [0.0, 0.0, 0.0, 0.0, 0.0] '
     'refused: needs 6 values for the 2 vehicles'),
    ({'vehicle_names': ['a', 'b'], 'initial_positions': [0.0] * 6, 'vehicle_files': ['x.yaml']},
     'vehicle_files'),
    ({'vehicle_names': ['a'], 'initial_positions': [0.0] * 3, 'robot_radii_m': [0.1, 0.2]}, 'robot_radii_m'),
])
def test_fleet_refusals_name_the_field_and_value(values, message):
    with pytest.raises(ValueError, match=message.replace('[', r'\[').replace(']', r'\]')):
        fleet_layout(_params(**values))


def test_schedule_sensors_on_their_grid_and_diagnostics_on_events_or_period():
    period_ns = int(DIAGNOSTICS_PERIOD_S * 1e9)
    schedule = ReportSchedule(sensor_period_ns=50_000_000)
    assert [t for t in range(0, 200_000_000, 10_000_000) if schedule.sensors_due(t)] == [0, 50_000_000,
                                                                                         100_000_000, 150_000_000]
    every_step = ReportSchedule(sensor_period_ns=0)
    assert all(every_step.sensors_due(t) for t in (0, 0, 1, 2))
    assert schedule.diagnostics_due(0, 0)
    assert schedule.reported(0, []) == []
    assert not schedule.diagnostics_due(period_ns - 1, 0)
    assert schedule.diagnostics_due(period_ns - 1, 1)                    # a new event
    events = ['e0', 'e1']
    assert schedule.reported(10, events) == ['e0', 'e1'] and schedule.reported(20, events + ['e2']) == ['e2']
    assert not schedule.diagnostics_due(20 + period_ns - 1, 3) and schedule.diagnostics_due(20 + period_ns, 3)


def _sim(events=(), failsafe_active=False, saturation=(), stopped=None):
    return SimpleNamespace(events=list(events), robot_radius_m=0.1, failsafe_active=failsafe_active,
                           saturation=list(saturation), saturated_steps=len(saturation), stopped=stopped)


def _by_name(statuses):
    return {s.name: (diagnostics.level_of(s), s.message, {kv.key: kv.value for kv in s.values}) for s in statuses}


def test_quiet_vehicle_reports_saturation_ok_its_counts_and_rtf():
    out = _by_name(vehicle_statuses(_sim(), [], steps_published=12, future_setpoints=3, rtf=1.5))
    assert set(out) == {contract.SIM_STATUS.format('saturation'), contract.SIM_PUBLISHED,
                        contract.SIM_STATUS.format('real_time_factor')}
    assert out[contract.SIM_STATUS.format('saturation')][0] == diagnostics.level_of(
        diagnostics.status('x', diagnostics.OK, ''))
    assert out[contract.SIM_PUBLISHED][2] == {'steps': '12', 'future_setpoints_refused': '3'}
    assert out[contract.SIM_STATUS.format('real_time_factor')][1:] == ('1.50x', {'rtf': '1.500'})


def test_collisions_failsafe_and_stop_are_errors_with_time_and_place():
    at = np.array([1.0, 2.0, 0.5])
    events = [Event('collision', 1.25, at), Event('collision', 2.0, at + 1.0),
              Event(VEHICLE_COLLISION, 3.0, at, {'other': 'cf2'}), Event('failsafe', 4.0, at)]
    stopped = SimpleNamespace(reason='tracking', time_s=5.0, __str__=lambda self: 'stopped')
    out = _by_name(vehicle_statuses(_sim(events, stopped=stopped), events[-1:], 1, 0, 1.0))
    error = diagnostics.level_of(diagnostics.status('x', diagnostics.ERROR, ''))
    level, message, values = out[contract.SIM_STATUS.format('collision')]
    assert level == error and message.startswith('collision 2:')
    assert values[contract.COLLISION_TIME_S] == '1.25' and values['x'] == '2.000'  # the first's time, newest's place
    level, message, values = out[contract.SIM_STATUS.format(VEHICLE_COLLISION)]
    assert level == error and 'with cf2' in message and values['collisions'] == '1'
    level, message, values = out[contract.SIM_FAILSAFE]
    assert level == error and '(failsafe)' in message and values[contract.FAILSAFE_TIME_S] == '4.0'
    assert out[contract.SIM_STATUS.format('stopped')][2] == {'reason': 'tracking', contract.STOP_TIME_S: '5.0'}


def test_failsafe_reported_while_active_or_new_and_saturation_while_limited():
    at = np.zeros(3)
    cleared = [Event('failsafe', 1.0, at), Event('failsafe_cleared', 2.0, at)]
    assert contract.SIM_FAILSAFE not in _by_name(vehicle_statuses(_sim(cleared), [], 0, 0, 1.0))
    out = _by_name(vehicle_statuses(_sim(cleared, failsafe_active=True), [], 0, 0, 1.0))
    assert '(failsafe_cleared)' in out[contract.SIM_FAILSAFE][1]      # the newest failsafe event
    out = _by_name(vehicle_statuses(_sim(saturation=['thrust']), [], 0, 0, 1.0))
    warn = diagnostics.level_of(diagnostics.status('x', diagnostics.WARN, ''))
    assert out[contract.SIM_STATUS.format('saturation')][:2] == (warn, 'rotor limits reduced thrust')
