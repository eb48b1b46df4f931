"""trajectory_node + position_controller + mavlink_bridge + mavlink_vehicle over UDP loopback, for PX4 and
ArduPilot: a short mission flown within a tracking bound; a controller killed mid-flight ends landed."""

import math

import numpy as np
import pytest

from quad_bringup.emulated.vehicle_graph import VEHICLE_FILE, free_udp_port, hover_in_offboard, running_graph
from quad_common.conversions import stamp_to_s

WAYPOINTS = [(0.0, 0.0, 1.0), (1.0, 0.0, 1.0), (1.0, 1.0, 1.3)]
SPEED_MPS = 0.3          # gentle: a stalled process on a loaded machine holds a tilted setpoint for a while
PATH_BOUND_M = 0.5       # distance of every flown point from the planned path (quiet machine: < 0.1 m)
HOLD_BOUND_M = 0.05      # hovering in offboard before the start: thrust normalisation and frames
TRACKING_BOUND_M = 1.0   # time-matched error: a loaded machine's stalls (the vehicle runs on the wall clock)
                         # show up here as lag; a quiet machine stays below 0.1 m
FINAL_MISS_M = 0.15


@pytest.fixture
def graph(tmp_path):
    with running_graph(tmp_path) as g:
        yield g


def _start_hovering_vehicle_in_offboard(procs, observer, flavour):
    # Timeouts well above a busy 2-core machine's scheduling stalls (the defaults suit a real vehicle): the
    # bridge's stale-setpoint and the controller's stale-odometry limits (test_bridge_busy.py flies the defaults).
    # PX4 keeps its default COM_OF_LOSS_T = 1 s: a longer one lets a stalled graph's last tilted setpoint fly on.
    hover_in_offboard(procs, observer, flavour, free_udp_port(), position=WAYPOINTS[0],
                      bridge={'autopilot': 'auto', 'setpoint_timeout_s': 1.0},
                      controller={'rate_hz': 50.0, 'odom_timeout_s': 1.0})


@pytest.mark.parametrize('flavour', ['px4', 'ardupilot'])
def test_mission_through_the_bridge_is_tracked(graph, flavour):
    procs, observer = graph
    _start_hovering_vehicle_in_offboard(procs, observer, flavour)
    flat = ','.join(str(c) for wp in WAYPOINTS for c in wp)
    procs.start('trajectory', ['-m', 'quad_trajectory.trajectory_node', '--ros-args', '-p', f'waypoints:=[{flat}]',
                               '-p', f'speed_mps:={SPEED_MPS}', '-p', 'start_delay_s:=1.0',
                               '-p', f'vehicle_file:={VEHICLE_FILE}'])
    observer.wait_for(lambda: observer.trajectory is not None, 'the trajectory')
    traj = observer.trajectory
    start_s = stamp_to_s(traj.header.stamp)
    # The plan starts start_delay_s after it was made: its second of hover is flown after it arrives.
    observer.wait_for(lambda: observer.odom[-1][0] >= start_s, 'odometry up to the start')
    with observer.lock:
        hold = [p for t, p in observer.odom if start_s - 1.0 <= t < start_s]
    assert hold and max(np.linalg.norm(np.array(hold) - WAYPOINTS[0], axis=1)) < HOLD_BOUND_M
    end_s = start_s + stamp_to_s(traj.points[-1].time_from_start)
    observer.wait_for(lambda: observer.odom[-1][0] > end_s + 2.0, 'the end of the mission', 120.0)

    with observer.lock:
        odom_t = np.array([t for t, _ in observer.odom])
        odom_p = np.array([p for _, p in observer.odom])
        refs = [(t, p) for t, p in observer.references if start_s <= t <= end_s + 2.0]
    assert len(refs) > 50, 'too few references during the mission'
    ref_t, ref_p = np.array([t for t, _ in refs]), np.array([p for _, p in refs])
    k = np.clip(np.searchsorted(odom_t, ref_t), 0, len(odom_t) - 1)
    errors = np.linalg.norm(odom_p[k] - ref_p, axis=1)
    flown = odom_p[(odom_t >= start_s) & (odom_t <= end_s + 2.0)]
    off_path = np.min(np.linalg.norm(flown[:, None, :] - ref_p[None, :, :], axis=2), axis=1)
    print(f'{flavour}: tracking error max {errors.max():.3f} m, rms {math.sqrt(np.mean(errors ** 2)):.3f} m; '
          f'distance from the path max {off_path.max():.3f} m')
    assert off_path.max() < PATH_BOUND_M
    assert errors.max() < TRACKING_BOUND_M
    assert np.linalg.norm(odom_p[-1] - WAYPOINTS[-1]) < FINAL_MISS_M
    values = observer.link()[1]
    assert values['losses'] == '0' and values['handler_errors'] == '0'


@pytest.mark.parametrize('flavour', ['ardupilot', 'px4'])
def test_controller_killed_mid_flight_ends_landed(graph, flavour):
    procs, observer = graph
    _start_hovering_vehicle_in_offboard(procs, observer, flavour)
    procs.stop('controller')
    land = 'LAND' if flavour == 'ardupilot' else 'AUTO.LAND'
    observer.wait_for(lambda: observer.link()[1].get('mode') == land, f'the bridge to command {land}')
    observer.wait_for(lambda: observer.link()[1].get('armed') == 'False', 'the vehicle to land and disarm')
    assert observer.position()[2] < 0.05
    setpoints = observer.diagnostics['mavlink_bridge: setpoints'][-1][2]
    assert int(setpoints['stale_events']) >= 1
    assert 'setpoints stale' in procs.log('bridge')
