"""Report metrics on a synthetic bag whose numbers are known in closed form.

The plan is a minimum-jerk move x(t) = L (10 s^3 - 15 s^4 + 6 s^5), s = t / T, from (0, 0, 1) to
(L, 0, 1); the vehicle flies the same move DELAY_S late (and hovers at both ends), so
error(t) = x(t) - x(t - DELAY_S), and completion is DELAY_S after the plan itself first satisfies
the completion rule.
"""

import json
import os
import select
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer

from quad_bringup.analysis.report import (
    Completion,
    closest_approach,
    compute_metrics,
    load_flight,
    metrics_table,
    write_report,
)
from quad_bringup.analysis.report_figures import FIGURES
from quad_bringup.commands import report as report_command
from quad_bringup.recording.recorder import typestore

L_M, T_S, DELAY_S, T0_S, RATE_HZ = 2.0, 4.0, 0.5, 10.0, 100
MISSED_WAYPOINT = (1.0, 0.03, 1.0)  # 3 cm beside the straight path
REAL_WOBBLE_M, REAL_LAND_S = 0.04, T0_S + T_S + 8.0


def min_jerk(t):
    s = np.clip(np.asarray(t, dtype=float) / T_S, 0, 1)
    x = L_M * (10 * s ** 3 - 15 * s ** 4 + 6 * s ** 5)
    v = L_M / T_S * (30 * s ** 2 - 60 * s ** 3 + 30 * s ** 4)
    a = L_M / T_S ** 2 * (60 * s - 180 * s ** 2 + 120 * s ** 3)
    return x, v, a


def stamp(ts, t_s):
    ns = int(round(t_s * 1e9))
    return ts.types['builtin_interfaces/msg/Time'](sec=ns // 10 ** 9, nanosec=ns % 10 ** 9)


def make_bag(path, storage=StoragePlugin.MCAP, end_s=T0_S + T_S + 2.0, collision_at_s=None, real=False):
    """real=True: like a real vehicle's bag: the estimator's position wobbles by 4 cm (0.7 Hz) and its
    velocity by 5 cm/s, so the 2 cm / 0.03 m/s rule is never met, and the vehicle lands at REAL_LAND_S
    (z from 1 m to 0 at 0.5 m/s) before the bag ends."""
    ts = typestore()
    M = ts.types
    v3 = M['geometry_msgs/msg/Vector3']
    quat = M['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0)
    header = M['std_msgs/msg/Header']
    point, pose = M['geometry_msgs/msg/Point'], M['geometry_msgs/msg/Pose']
    pose_stamped = M['geometry_msgs/msg/PoseStamped']
    twist = M['geometry_msgs/msg/Twist']

    def traj_point(t):
        x, v, a = min_jerk(t)
        tf = M['geometry_msgs/msg/Transform'](translation=v3(x=float(x), y=0.0, z=1.0), rotation=quat)
        ns = int(round(t * 1e9))
        return M['trajectory_msgs/msg/MultiDOFJointTrajectoryPoint'](
            transforms=[tf], velocities=[twist(linear=v3(x=float(v), y=0.0, z=0.0), angular=v3(x=0.0, y=0.0, z=0.0))],
            accelerations=[twist(linear=v3(x=float(a), y=0.0, z=0.0), angular=v3(x=0.0, y=0.0, z=0.0))],
            time_from_start=M['builtin_interfaces/msg/Duration'](sec=ns // 10 ** 9, nanosec=ns % 10 ** 9))

    traj = M['trajectory_msgs/msg/MultiDOFJointTrajectory'](
        header=header(stamp=stamp(ts, T0_S), frame_id='map'), joint_names=['base_link'],
        points=[traj_point(k / RATE_HZ) for k in range(int(T_S * RATE_HZ) + 1)])
    waypoints = M['nav_msgs/msg/Path'](header=header(stamp=stamp(ts, T0_S), frame_id='map'), poses=[
        pose_stamped(header=header(stamp=stamp(ts, T0_S), frame_id='map'),
                     pose=pose(position=point(x=float(w[0]), y=float(w[1]), z=float(w[2])), orientation=quat))
        for w in [(0, 0, 1), MISSED_WAYPOINT, (L_M, 0, 1)]])
    marker = M['visualization_msgs/msg/Marker']
    box = marker(header=header(stamp=stamp(ts, T0_S), frame_id='map'), ns='obstacles', id=0, type=1, action=0,
                 pose=pose(position=point(x=1.0, y=0.6, z=1.0), orientation=quat), scale=v3(x=0.4, y=0.4, z=2.0),
                 color=M['std_msgs/msg/ColorRGBA'](r=0.5, g=0.5, b=0.5, a=0.5),
                 lifetime=M['builtin_interfaces/msg/Duration'](sec=0, nanosec=0), frame_locked=False, points=[],
                 colors=[], texture_resource='', texture=M['sensor_msgs/msg/CompressedImage'](
                     header=header(stamp=stamp(ts, 0), frame_id=''), format='', data=np.zeros(0, np.uint8)),
                 uv_coordinates=[], text='', mesh_resource='',
                 mesh_file=M['visualization_msgs/msg/MeshFile'](filename='', data=np.zeros(0, np.uint8)),
                 mesh_use_embedded_materials=False)
    markers = M['visualization_msgs/msg/MarkerArray'](markers=[box])
    cov9, cov36 = np.zeros(9), np.zeros(36)

    def odom(t):
        x, v, _ = min_jerk(t - T0_S - DELAY_S)
        y, z = 0.0, 1.0
        if real:
            y = REAL_WOBBLE_M * np.sin(2 * np.pi * 0.7 * t)
            v = v + 0.05 * np.cos(2 * np.pi * 0.7 * t)
            z = max(0.0, 1.0 - 0.5 * max(0.0, t - REAL_LAND_S))
        return M['nav_msgs/msg/Odometry'](
            header=header(stamp=stamp(ts, t), frame_id='map'), child_frame_id='base_link',
            pose=M['geometry_msgs/msg/PoseWithCovariance'](pose=pose(position=point(x=float(x), y=float(y), z=z),
                                                                     orientation=quat), covariance=cov36),
            twist=M['geometry_msgs/msg/TwistWithCovariance'](
                twist=twist(linear=v3(x=float(v), y=0.0, z=0.0), angular=v3(x=0.0, y=0.0, z=0.0)), covariance=cov36))

    def command(t):
        return M['sensor_msgs/msg/Imu'](header=header(stamp=stamp(ts, t), frame_id='base_link'), orientation=quat,
                                        orientation_covariance=cov9, angular_velocity=v3(x=0.0, y=0.0, z=0.0),
                                        angular_velocity_covariance=cov9,
                                        linear_acceleration=v3(x=0.0, y=0.0, z=9.81),
                                        linear_acceleration_covariance=cov9)

    with Writer(path, version=9, storage_plugin=storage) as writer:
        conns = {name: writer.add_connection(name, msgtype, typestore=ts) for name, msgtype in [
            ('trajectory', 'trajectory_msgs/msg/MultiDOFJointTrajectory'),
            ('trajectory/waypoints', 'nav_msgs/msg/Path'),
            ('trajectory/markers', 'visualization_msgs/msg/MarkerArray'), ('odom', 'nav_msgs/msg/Odometry'),
            ('cmd/attitude_thrust', 'sensor_msgs/msg/Imu'), ('diagnostics', 'diagnostic_msgs/msg/DiagnosticArray'),
            ('/clock', 'rosgraph_msgs/msg/Clock')]}

        def write(topic, t, msg):
            writer.write(conns[topic], int(t * 1e9), ts.serialize_cdr(msg, conns[topic].msgtype))

        write('trajectory', T0_S - 1, traj)
        write('trajectory/waypoints', T0_S - 1, waypoints)
        write('trajectory/markers', T0_S - 1, markers)
        for k in range(int((T0_S - 1) * RATE_HZ), int(round(end_s * RATE_HZ)) + 1):
            write('odom', k / RATE_HZ, odom(k / RATE_HZ))
            write('cmd/attitude_thrust', k / RATE_HZ, command(k / RATE_HZ))
            if not real:   # a simulator's bag: sim_node's /clock (a real vehicle's graph has none)
                write('/clock', k / RATE_HZ, M['rosgraph_msgs/msg/Clock'](clock=stamp(ts, k / RATE_HZ)))
        if collision_at_s is not None:
            kv = M['diagnostic_msgs/msg/KeyValue']
            status = M['diagnostic_msgs/msg/DiagnosticStatus'](
                level=2, name='sim_node: collision', message='hit obstacle 0', hardware_id='',
                values=[kv(key='collision_time_s', value=repr(collision_at_s)), kv(key='x', value='1.0')])
            write('diagnostics', collision_at_s, M['diagnostic_msgs/msg/DiagnosticArray'](
                header=header(stamp=stamp(ts, collision_at_s), frame_id=''), status=[status]))
    return path


def expected_completion_s(rule=None):
    """First plan time (on the 100 Hz grid) within tolerance of the end at low speed, plus the delay."""
    rule = rule or Completion()
    t = np.arange(0, T_S + 1e-9, 1 / RATE_HZ)
    x, v, _ = min_jerk(t)
    ok = (np.abs(x - L_M) <= rule.position_tolerance_m) & (np.abs(v) <= rule.speed_tolerance_mps)
    return t[np.argmax(ok)] + DELAY_S


@pytest.mark.parametrize('storage', [StoragePlugin.MCAP, StoragePlugin.SQLITE3], ids=['mcap', 'sqlite3'])
def test_metrics_match_closed_form(tmp_path, storage):
    metrics = compute_metrics(load_flight(make_bag(tmp_path / 'bag', storage)))
    t_done = expected_completion_s()
    t = np.arange(0, t_done + 1e-9, 1 / RATE_HZ)
    err = min_jerk(t)[0] - min_jerk(t - DELAY_S)[0]
    assert metrics['time_planned_s'] == pytest.approx(T_S)
    assert metrics['time_actual_s'] == pytest.approx(t_done, abs=1e-9)
    assert metrics['time_over_s'] == pytest.approx(t_done - T_S, abs=1e-9)
    assert metrics['length_planned_m'] == pytest.approx(L_M)
    assert metrics['length_actual_m'] == pytest.approx(min_jerk(t_done - DELAY_S)[0])
    assert metrics['avg_velocity_mps'] == pytest.approx(min_jerk(t_done - DELAY_S)[0] / t_done)
    assert metrics['rmse_m'] == pytest.approx(np.sqrt(np.mean(err ** 2)), rel=1e-6)
    assert metrics['max_error_m'] == pytest.approx(np.max(err), rel=1e-6)
    assert 0.45 < metrics['max_error_m'] < 0.47  # ~ peak speed 0.9375 m/s x 0.5 s
    assert metrics['waypoint_miss_max_m'] == pytest.approx(0.03)
    assert metrics['completed'] is True and metrics['collided'] is False
    assert metrics['max_speed_mps'] == pytest.approx(1.875 * L_M / T_S, rel=1e-3)


def test_tolerances_are_configurable(tmp_path):
    rule = Completion(position_tolerance_m=0.1, speed_tolerance_mps=0.2)
    metrics = compute_metrics(load_flight(make_bag(tmp_path / 'bag')), rule)
    assert metrics['time_actual_s'] == pytest.approx(expected_completion_s(rule), abs=1e-9)
    assert metrics['time_actual_s'] < expected_completion_s()


def test_unfinished_flight_counts_until_the_end_of_the_bag(tmp_path):
    end_s = T0_S + 3.0
    metrics = compute_metrics(load_flight(make_bag(tmp_path / 'bag', end_s=end_s)))
    assert metrics['completed'] is False
    assert metrics['time_actual_s'] == pytest.approx(end_s - T0_S)
    assert metrics['length_actual_m'] == pytest.approx(min_jerk(3.0 - DELAY_S)[0])


def test_collision_from_diagnostics(tmp_path):
    """The collision is the contract's key `collision_time_s`, read at full precision (was 1 ms)."""
    at_s = T0_S + 1.5 + 1.234567891e-4
    metrics = compute_metrics(load_flight(make_bag(tmp_path / 'bag', collision_at_s=at_s)))
    assert metrics['collided'] is True
    assert metrics['completed'] is False
    assert metrics['collision_time_s'] == at_s - T0_S
    assert metrics['errors'] == ['1.50 s sim_node: collision: hit obstacle 0']


def test_a_bag_without_a_simulator_does_not_say_it_did_not_collide(tmp_path):
    """A bridge bag has no collision information: `Collided` is n/a, not False."""
    metrics = compute_metrics(load_flight(make_bag(tmp_path / 'bag', end_s=REAL_LAND_S + 4.0, real=True)),
                              Completion(settle_s=2.0))
    assert metrics['collided'] is None
    assert metrics_table(metrics).rstrip(' |').endswith('| n/a')
    sim = compute_metrics(load_flight(make_bag(tmp_path / 'sim')), Completion())
    assert sim['collided'] is False and metrics_table(sim).rstrip(' |').endswith('| False')


def test_report_says_whose_speed_and_why_time_actual_is_shorter(tmp_path):
    """A newcomer's friction: `speed_mps: None` for the default mission; time actual < planned unexplained."""
    from quad_bringup.analysis.report import report_markdown
    metrics = compute_metrics(load_flight(make_bag(tmp_path / 'bag')), Completion(position_tolerance_m=0.2,
                                                                                  speed_tolerance_mps=0.5))
    assert metrics['completed'] and metrics['time_over_s'] < 0
    text = report_markdown({**metrics, 'speed_mps': None, 'mission': 'm'}, [], 'r')
    assert 'speed_mps: None' not in text and "speed_mps: the mission's (no --speed)" in text
    assert 'time actual ends at completion' in text


def test_report_says_when_the_flight_began_away_from_the_plan(tmp_path):
    """A bridge flight started 0.5 m from the plan's start joined it silently."""
    from quad_bringup.analysis.report import report_markdown
    flight = load_flight(make_bag(tmp_path / 'bag'))
    on_plan = compute_metrics(flight, Completion())
    assert on_plan['start_offset_m'] < 0.01 and 'JOINED' not in report_markdown(on_plan, [], 'r')
    flight.position = flight.position + np.array([0.0, 0.5, 0.0])
    away = compute_metrics(flight, Completion())
    assert away['start_offset_m'] == pytest.approx(0.5, abs=0.01)
    assert 'was 0.500 m from the plan\'s first point' in report_markdown(away, [], 'r')
    assert 'JOINED' in report_markdown(away, [], 'r')


def test_closest_approach_uses_segments():
    path = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    assert closest_approach(path, np.array([0.5, 0.2, 0])) == pytest.approx(0.2)
    assert closest_approach(path, np.array([2.0, 0, 0])) == pytest.approx(1.0)


def test_report_writes_metrics_markdown_and_figures(tmp_path):
    bag = make_bag(tmp_path / 'run' / 'bag')
    metrics = write_report(bag, tmp_path / 'run', extra={'mission': 'synthetic', 'controller': 'pd'})
    on_disk = json.loads((tmp_path / 'run' / 'metrics.json').read_text())
    assert on_disk == metrics
    assert on_disk['mission'] == 'synthetic'
    md = (tmp_path / 'run' / 'report.md').read_text()
    assert 'Time planned (s)' in md and 'Avg. velocity (m/s)' in md and 'RMSE (m)' in md
    figures = sorted(p.name for p in (tmp_path / 'run' / 'figures').glob('*.png'))
    assert figures == ['commands.png', 'error_over_time.png', 'fig1_position_velocity.png', 'fig2_path_3d.png',
                       'fig4_plane_views.png', 'fig5_axis_tracking.png']
    assert all(f'figures/{name}' in md for name in figures)
    assert all((tmp_path / 'run' / 'figures' / n).stat().st_size > 10_000 for n in figures)


def test_a_fleets_reports_get_their_figures_drawn_side_by_side(tmp_path):
    """fleet_graph.draw_reports_figures: each report directory its own flight's figures, linked from its
    report.md; a flight that cannot be drawn names its report."""
    from quad_bringup.running.fleet_graph import draw_reports_figures

    flights, metrics = {}, {}
    for name, end_s in (('cf1', None), ('cf2', T0_S + T_S / 2)):
        flight = load_flight(make_bag(tmp_path / name / 'bag', **({'end_s': end_s} if end_s else {})))
        flights[tmp_path / name] = flight
        metrics[tmp_path / name] = write_report(tmp_path / name / 'bag', tmp_path / name, figures=False, flight=flight)
        assert 'figures/' not in (tmp_path / name / 'report.md').read_text()
    draw_reports_figures(flights, metrics)
    for d in flights:
        md = (d / 'report.md').read_text()
        figures = sorted(p.name for p in (d / 'figures').glob('*.png'))
        assert len(figures) == 6 and all(f'figures/{n}' in md for n in figures)
    # cf2's flight ends half way: its position figure differs from cf1's
    assert ((tmp_path / 'cf1' / 'figures' / 'fig1_position_velocity.png').read_bytes()
            != (tmp_path / 'cf2' / 'figures' / 'fig1_position_velocity.png').read_bytes())
    broken = load_flight(make_bag(tmp_path / 'cf3' / 'bag'))
    broken.odom_t = None
    with pytest.raises(RuntimeError, match='cf3: figures not drawn'):
        draw_reports_figures({tmp_path / 'cf1': flights[tmp_path / 'cf1'], tmp_path / 'cf3': broken}, metrics |
                             {tmp_path / 'cf3': {}})


def test_report_command(tmp_path, capsys):
    bag = make_bag(tmp_path / 'run' / 'bag')
    parser = __import__('argparse').ArgumentParser()
    report_command.add_arguments(parser)
    assert report_command.run(parser.parse_args([str(bag)])) == 0
    out = capsys.readouterr().out
    metrics = json.loads((tmp_path / 'run' / 'metrics.json').read_text())
    assert f'{metrics["time_actual_s"]:.2f}' in out
    assert report_command.run(parser.parse_args([str(tmp_path / 'missing')])) == 2
    assert 'no such directory' in capsys.readouterr().err


# --- a real flight: the estimator never meets the simulator's 2 cm rule, then the vehicle lands ---------------

def test_real_flight_is_scored_until_the_plan_end_plus_settle_not_into_the_landing(tmp_path):
    """Issue: on a real estimator the 2 cm / 0.03 m/s rule is never met, the window ran into the landing and a
    7 cm flight was reported at 0.84 m RMSE."""
    flight = load_flight(make_bag(tmp_path / 'bag', end_s=REAL_LAND_S + 4.0, real=True))
    metrics = compute_metrics(flight, Completion(settle_s=2.0))
    assert metrics['completed'] is False
    window = metrics['scored_window']
    assert window['end_s'] == pytest.approx(T_S + 2.0) and window['ends_at'].startswith("the plan's end + settle_s 2")
    assert window['bag_end_s'] == pytest.approx(REAL_LAND_S + 4.0 - T0_S)
    assert metrics['time_actual_s'] == pytest.approx(T_S + 2.0)
    # what was scored: the 0.5 s delay and the 4 cm wobble, not the 1 m descent
    t = np.arange(0, T_S + 2.0 + 1e-9, 1 / RATE_HZ)
    ex = min_jerk(t)[0] - min_jerk(t - DELAY_S)[0]
    ey = REAL_WOBBLE_M * np.sin(2 * np.pi * 0.7 * (t + T0_S))
    assert metrics['rmse_m'] == pytest.approx(np.sqrt(np.mean(ex ** 2 + ey ** 2)), rel=1e-3)
    assert metrics['completion_rule']['settle_s'] == 2.0
    into_landing = compute_metrics(flight, Completion(settle_s=100.0))   # the old window: to the bag's end
    assert into_landing['scored_window']['ends_at'].startswith("the bag's last odometry")
    assert into_landing['rmse_m'] > 1.5 * metrics['rmse_m'] and into_landing['max_error_m'] > 0.99


def test_real_vehicle_tolerances_from_its_yaml_complete_the_same_flight(tmp_path):
    from quad_common.vehicle import load_vehicle
    from quad_trajectory.mission import DEFAULT_VEHICLE_PATH

    px4 = load_vehicle(DEFAULT_VEHICLE_PATH.replace('crazyflie', 'px4_quad'))
    rule = Completion.for_vehicle(px4)
    assert (rule.position_tolerance_m, rule.speed_tolerance_mps, rule.source) == (0.10, 0.10, 'vehicle px4_quad')
    bag = make_bag(tmp_path / 'bag', end_s=REAL_LAND_S + 4.0, real=True)
    metrics = write_report(bag, tmp_path / 'out', rule=rule)
    assert metrics['completed'] is True and metrics['scored_window']['ends_at'] == 'completion'
    assert metrics['time_actual_s'] < T_S + 1.0
    text = (tmp_path / 'out' / 'report.md').read_text()
    assert '(vehicle px4_quad)' in text and 'Scored window' in text and 'ending at completion' in text
    assert json.loads((tmp_path / 'out' / 'metrics.json').read_text())['completion_rule']['source'] == \
        'vehicle px4_quad'
    # a command-line value overrides the vehicle's, and a bad one is named
    assert Completion.for_vehicle(px4, settle_s=5.0).source == 'vehicle px4_quad + command line'
    with pytest.raises(ValueError, match=r'--position-tolerance -1 refused: must be > 0 and <= 100 m'):
        Completion.for_vehicle(px4, position_tolerance_m=-1.0)
    px4.extra['completion'] = {'position_tolerance': 0.1}
    with pytest.raises(ValueError, match=r'vehicle px4_quad: completion = .* may only hold position_tolerance_m'):
        Completion.for_vehicle(px4)


def test_report_command_takes_the_vehicles_rule(tmp_path, capsys):
    from quad_trajectory.mission import DEFAULT_VEHICLE_PATH

    bag = make_bag(tmp_path / 'bag', end_s=REAL_LAND_S + 4.0, real=True)
    parser = __import__('argparse').ArgumentParser()
    report_command.add_arguments(parser)
    args = parser.parse_args([str(bag), '--out', str(tmp_path / 'out'), '--vehicle',
                              DEFAULT_VEHICLE_PATH.replace('crazyflie', 'px4_quad'), '--settle', '1.5'])
    assert report_command.run(args) == 0
    rule = json.loads((tmp_path / 'out' / 'metrics.json').read_text())['completion_rule']
    assert rule == {'position_tolerance_m': 0.1, 'speed_tolerance_mps': 0.1, 'settle_s': 1.5,
                    'source': 'vehicle px4_quad + command line'}


def test_the_figure_worker_whose_fly_is_gone_ends_without_a_traceback(tmp_path):
    """A signal to fly while the figures are drawn: fly exits, the worker's answer meets a closed pipe."""
    import json
    import subprocess
    import sys

    worker = subprocess.Popen([sys.executable, '-m', 'quad_bringup.analysis.figure_worker'], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    worker.stdout.close()   # fly gone: nobody reads the answer
    _, err = worker.communicate(json.dumps({'bag': str(tmp_path / 'nobag'), 'out': str(tmp_path)}) + '\n',
                                timeout=120)
    assert 'Traceback' not in err and 'BrokenPipeError' not in err, err


def test_the_record_check_counts_the_newest_sim_count_up_to_its_own_stamp():
    """fly's monitor may hold an older `sim_node: published` than the bag (received late on a loaded machine): the
    newer of the two counts, checked up to its own stamp; a count newer than what was recorded shows as missing."""
    from quad_bringup.analysis.metrics import Flight, record_check
    stamps = np.arange(1, 11, dtype=np.int64) * 10_000_000          # 10 steps recorded, 10 ms apart
    flight = Flight(odom_t=stamps * 1e-9, position=np.zeros((10, 3)), velocity=np.zeros((10, 3)),
                    euler=np.zeros((10, 3)), odom_stamps_ns=stamps, clock_stamps_ns=stamps,
                    sim_published=(int(stamps[-1]), 10))
    stale = record_check(flight, (int(stamps[3]), 4))               # the monitor's older count: the bag's wins
    assert stale['steps_published'] == stale['odom_recorded'] == stale['/clock_recorded'] == 10
    assert stale['complete']
    older_bag = Flight(**{**flight.__dict__, 'sim_published': (int(stamps[3]), 4)})
    upto = record_check(older_bag)                                   # only the bag's older count: up to its stamp
    assert upto['steps_published'] == upto['odom_recorded'] == 4 and upto['complete']
    newer = record_check(flight, (int(stamps[-1]) + 20_000_000, 12))  # the simulator published 2 steps more
    assert newer['missing'] == {'odom': 2, '/clock': 2} and not newer['complete']


def test_the_figure_worker_draws_a_pickled_flight_without_the_bag_reader(tmp_path):
    """fly hands the worker the Flight it has loaded: the worker imports matplotlib and the figures, not the report
    module's bag reader (rosbags) or the ROS messages, and draws every figure."""
    import json
    import pickle
    import subprocess
    import sys

    with open(tmp_path / 'flight.pickle', 'wb') as f:
        pickle.dump(load_flight(make_bag(tmp_path / 'bag')), f)
    done = subprocess.run([sys.executable, '-X', 'importtime', '-m', 'quad_bringup.analysis.figure_worker'], text=True,
                          input=json.dumps({'flight': str(tmp_path / 'flight.pickle'), 'out': str(tmp_path)}) + '\n',
                          capture_output=True, timeout=300)
    assert sorted(json.loads(done.stdout)['figures']) == sorted(f'figures/{name}' for name, _ in FIGURES)
    imported = {line.rsplit('|', 1)[-1].strip() for line in done.stderr.splitlines() if line.startswith('import')}
    assert not {m for m in imported if m.split('.')[0] in ('rosbags', 'rclpy', 'nav_msgs')}
    assert 'quad_bringup.analysis.report' not in imported


def test_the_figure_worker_exits_without_python_finalization_once_it_has_answered(tmp_path):
    """fly reaps the worker after its answer: it ends at once (os._exit), its answer and figures complete; an exit
    handler registered in it never runs."""
    import json
    import pickle
    import subprocess
    import sys

    with open(tmp_path / 'flight.pickle', 'wb') as f:
        pickle.dump(load_flight(make_bag(tmp_path / 'bag')), f)
    run_worker = ('import atexit, runpy, sys; atexit.register(lambda: print("FINALIZED", file=sys.stderr)); '
                  'runpy.run_module("quad_bringup.analysis.figure_worker", run_name="__main__")')
    done = subprocess.run([sys.executable, '-c', run_worker], text=True, capture_output=True, timeout=300,
                          input=json.dumps({'flight': str(tmp_path / 'flight.pickle'), 'out': str(tmp_path)}) + '\n')
    assert done.returncode == 0, done.stderr
    assert 'FINALIZED' not in done.stderr
    figures = json.loads(done.stdout)['figures']
    assert sorted(figures) == sorted(f'figures/{name}' for name, _ in FIGURES)
    assert all((tmp_path / f).stat().st_size > 0 for f in figures)


def _children() -> set[int]:
    """This process's children, zombies (exited, not reaped) included."""
    me, kids = str(os.getpid()), set()
    for entry in os.listdir('/proc'):
        try:
            stat = (Path('/proc') / entry / 'stat').read_text() if entry.isdigit() else ''
        except OSError:   # ended meanwhile
            continue
        if stat and stat.rsplit(')', 1)[1].split()[1] == me:
            kids.add(int(entry))
    return kids


def test_figures_drawn_in_parts_are_those_drawn_in_one(tmp_path):
    """report_figures.draw_run split between this process and forked children gives the same files, byte for byte,
    in the same order, so report.md links the same figures; every child is reaped."""
    from quad_bringup.analysis import report_figures
    from quad_bringup.analysis.report import write_markdown

    flight = load_flight(make_bag(tmp_path / 'bag'))
    metrics = {'mission': 'synthetic', **compute_metrics(flight, Completion())}
    before = _children()
    drawn = {parts: report_figures.draw_run(flight, tmp_path / f'in{parts}', parts) for parts in (1, 2, 3)}
    assert _children() == before
    names = [[p.relative_to(tmp_path / f'in{parts}') for p in drawn[parts]] for parts in drawn]
    assert names[0] == [Path('figures') / name for name, _ in FIGURES] and names[1] == names[0] == names[2]
    for parts in drawn:
        assert [p.read_bytes() for p in drawn[parts]] == [p.read_bytes() for p in drawn[1]]
        write_markdown(metrics, tmp_path / f'in{parts}', drawn[parts])
    assert len({(tmp_path / f'in{parts}' / 'report.md').read_text() for parts in drawn}) == 1


def _broken(how):
    def draw(flight, path):
        if how == 'raises':
            raise ValueError(f'cannot draw {Path(path).name}')
        if how == 'dies':
            os.kill(os.getpid(), signal.SIGKILL)
        select.select([os.pipe()[0]], [], [])   # hangs: nothing is ever written
    return draw


@pytest.mark.parametrize('how, error, message', [
    ('raises', ValueError, 'cannot draw'),
    ('dies', ChildProcessError, r'died \(signal SIGKILL\) without an answer'),
    ('hangs', ChildProcessError, 'gave no answer in 2 s'),
])
def test_a_forked_part_that_fails_is_an_error_not_a_hang(tmp_path, monkeypatch, how, error, message):
    """A child that raises gives its exception to the caller; one that dies or hangs a ChildProcessError naming its
    figures (a hung one after PART_TIMEOUT_S, then killed); none is left running or unreaped."""
    from quad_bringup.analysis import report_figures

    flight = load_flight(make_bag(tmp_path / 'bag'))
    child = report_figures.split_parts([name for name, _ in FIGURES], 2)[1]
    figures = [(name, _broken(how) if k == child[0] else draw) for k, (name, draw) in enumerate(FIGURES)]
    monkeypatch.setattr(report_figures, 'FIGURES', figures)
    monkeypatch.setattr(report_figures, 'PART_TIMEOUT_S', 2.0)
    before = _children()
    with pytest.raises(error, match=message):
        report_figures.draw_run(flight, tmp_path, 2)
    assert _children() == before


def test_a_forked_part_dies_with_its_caller(tmp_path):
    """The caller SIGKILLed while its parts draw: the forked child ends too (PR_SET_PDEATHSIG), not run on under
    init. Each says its pid in one write (print under PYTHONUNBUFFERED writes the number and the newline apart, and
    the two processes' lines could interleave)."""
    script = ('import os, select, sys\n'
              'from quad_bringup.analysis import report_figures as rf\n'
              'def hold(flight, path):\n'
              '    os.write(1, f"{os.getpid()}\\n".encode())\n'
              '    select.select([os.pipe()[0]], [], [])\n'
              'rf.FIGURES = [(name, hold) for name, _ in rf.FIGURES]\n'
              'rf.draw_all(None, sys.argv[1], 2)\n')
    caller = subprocess.Popen([sys.executable, '-c', script, str(tmp_path)], stdout=subprocess.PIPE, text=True)
    holding = {int(caller.stdout.readline()) for _ in range(2)}   # the caller and its child, each in its figure
    (child,) = holding - {caller.pid}
    alive = os.pidfd_open(child)
    try:
        caller.kill()
        caller.wait()
        assert select.select([alive], [], [], 30)[0], 'the forked part outlived its caller'
    finally:
        if not select.select([alive], [], [], 0)[0]:
            os.kill(child, signal.SIGKILL)
        os.close(alive)


def test_odometry_and_setpoints_read_from_their_bytes_give_the_flight_deserialising_gives(tmp_path, monkeypatch):
    """Bags written with rosbags (the offline loop's, and a simulator's with /clock): odometry, setpoints, /clock and
    the plan read from the CDR bytes (no message object) give exactly the Flight that deserialising every message
    gives; only the other topics deserialise."""
    from quad_bringup.analysis import report
    from quad_bringup.offline.closed_loop import LoopOptions, fly_offline
    from quad_common.paths import resolve_config

    offline = tmp_path / 'offline'
    fly_offline(resolve_config('config/missions/maze.yaml'), LoopOptions(speed_mps=2.0, bag_dir=offline))
    simulated = make_bag(tmp_path / 'simulated')
    store = report.typestore()
    deserialised = []
    plain = store.deserialize_cdr
    monkeypatch.setattr(store, 'deserialize_cdr', lambda raw, kind: deserialised.append(kind) or plain(raw, kind))
    read_as_bytes = report.FROM_BYTES
    for bag in (offline, simulated):
        deserialised.clear()
        monkeypatch.setattr(report, 'FROM_BYTES', read_as_bytes)
        from_bytes = report.load_flight(bag)
        assert not {'nav_msgs/msg/Odometry', 'sensor_msgs/msg/Imu', 'rosgraph_msgs/msg/Clock',
                    'trajectory_msgs/msg/MultiDOFJointTrajectory'} & set(deserialised)
        monkeypatch.setattr(report, 'FROM_BYTES', {})
        objects = report.load_flight(bag)
        assert deserialised.count('nav_msgs/msg/Odometry') == len(objects.odom_t) > 100
        assert len(from_bytes.cmd_t) > 100
        for name in ('odom_t', 'position', 'velocity', 'euler', 'odom_stamps_ns', 'odom_record_ns', 'cmd_t',
                     'cmd_specific_force', 'cmd_euler', 'cmd_record_ns', 'clock_stamps_ns'):
            assert np.array_equal(getattr(from_bytes, name), getattr(objects, name)), (bag.name, name)
        assert from_bytes.traj_start_s == objects.traj_start_s
        if bag == simulated:   # (the offline loop's bag has no plan)
            assert 'trajectory_msgs/msg/MultiDOFJointTrajectory' in deserialised
            for name in ('times_s', 'position', 'velocity', 'acceleration'):
                assert np.array_equal(getattr(from_bytes.trajectory, name), getattr(objects.trajectory, name)), name
    assert len(from_bytes.clock_stamps_ns) > 100


def test_bag_metadata_is_read_with_ruamels_c_parser():
    """rosbags reads metadata.yaml and every topic's QoS with ruamel.yaml (typ 'safe'): with ruamel.yaml.clib, in the
    pinned set, that is its C parser (a 16-topic bag opens ~0.15 s faster than with the pure-Python one)."""
    from rosbags.rosbag2 import metadata  # its YAML is ruamel.yaml's

    yaml_reader = metadata.YAML(typ='safe')
    yaml_reader.load('a: 1')
    assert type(yaml_reader.parser).__name__ == 'CParser'
