"""`quadflight report` of a flight recorded as on a real vehicle: the emulated autopilot,
mavlink_bridge, position_controller with the real-vehicle profile, the recorder, `land` after the plan. The
scored window ends at completion by the vehicle's own tolerances (px4_quad.yaml: 10 cm, 0.1 m/s) or at the plan's
end plus its settle time, never in the landing that follows; the report says which, and what it scored."""

import pytest

from quad_bringup.emulated.mission_flight import fly_mission, report
from quad_bringup.emulated.vehicle_graph import running_graph

WAYPOINTS = [(0.0, 0.0, 1.5), (1.5, 0.0, 1.5), (1.5, 1.0, 1.8)]
SPEED_MPS = 0.5
SETTLE_S = 3.0            # px4_quad.yaml completion.settle_s
RMSE_BOUND_M = 0.15       # a quiet machine: ~0.05 m (docs/bridge.md); the landing scored would be ~1 m


@pytest.mark.parametrize('flavour', ['ardupilot'])
def test_report_of_a_bridge_flight_scores_the_plan_not_the_landing(tmp_path, flavour):
    with running_graph(tmp_path) as (procs, observer):
        flight = fly_mission(procs, observer, tmp_path, flavour, WAYPOINTS, SPEED_MPS,
                             bridge_params={'setpoint_timeout_s': 1.0},     # a busy 2-core machine's stalls
                             controller_params={'odom_timeout_s': 1.0})
    m = flight.metrics
    window = m['scored_window']
    print(f'{flavour}: time {m["time_planned_s"]:.2f} / {m["time_actual_s"]:.2f} s, rmse {m["rmse_m"]:.3f} m, '
          f'max {m["max_error_m"]:.3f} m, window {window}')
    # the bag runs on through the landing; the window stops before it
    assert window['bag_end_s'] > m['time_planned_s'] + SETTLE_S + 1.0
    assert window['end_s'] <= m['time_planned_s'] + SETTLE_S + 1e-6
    assert window['ends_at'] == 'completion' or window['ends_at'].startswith("the plan's end + settle_s")
    assert m['rmse_m'] < RMSE_BOUND_M
    assert m['waypoint_miss_max_m'] < 0.1
    assert 'Scored window' in flight.report_md and 'px4_quad' in flight.report_md
    # a tolerance never met (a micrometre): the window ends at the plan's end + settle_s, still before the landing
    strict, strict_md = report(flight.bag, tmp_path / 'strict', procs.env, '--position-tolerance', '1e-6')
    window = strict['scored_window']
    assert window['ends_at'].startswith("the plan's end + settle_s 3 s")
    assert abs(window['end_s'] - (strict['time_planned_s'] + SETTLE_S)) < 0.05
    assert strict['rmse_m'] < RMSE_BOUND_M
    assert "the plan's end + settle_s" in strict_md
