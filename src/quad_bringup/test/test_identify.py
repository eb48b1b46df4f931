"""quadflight identify on rosbag2 bags flown by the plant family: the attitude lag within 15 % of the member's
own loop (quad_sim.attitude_poles.attitude_mean_delay_s), the thrust scale of its mass / thrust error, a usable
profile."""

import subprocess
import sys

import numpy as np
import pytest
import yaml

from quad_bringup.analysis.identify import identify, profile, quality_refusal, read_identification
from quad_bringup.analysis.report import load_flight
from quad_bringup.offline.closed_loop import LoopOptions, fly_offline
from quad_common.paths import REPO_ROOT, resolve_config
from quad_common.vehicle import load_vehicle
from quad_sim.attitude_poles import attitude_mean_delay_s

MAZE = resolve_config('config/missions/maze.yaml')
CRAZYFLIE = resolve_config('config/vehicles/crazyflie.yaml')


def flown_bag(tmp_path, member):
    """A bag of the seed pd flying the maze at 1 m/s on `member` (pd: no roll/pitch rate feed-forward)."""
    bag = tmp_path / f'{member}-bag'
    fly_offline(MAZE, LoopOptions(speed_mps=1.0, plant=member, bag_dir=bag))
    return bag


@pytest.mark.parametrize('member', ['nominal', 'slow_motors_72ms', 'autopilot_so3', 'autopilot_lag'])
def test_identified_attitude_lag_within_15_percent(tmp_path, member):
    vehicle = load_vehicle(CRAZYFLIE, plant=member)
    truth_s = attitude_mean_delay_s(vehicle)
    result = identify(load_flight(flown_bag(tmp_path, member)))
    for axis in ('roll', 'pitch'):
        fit = result[axis]
        assert fit['lag_s'] == pytest.approx(truth_s, rel=0.15), (axis, fit)
        low, high = fit['lag_ci95_s']
        assert low < fit['lag_s'] < high and high - low < 0.3 * truth_s and fit['blocks'] >= 3
        assert fit['gain'] == pytest.approx(1.0, abs=0.05)
    assert result['thrust_scale'] == pytest.approx(1.0, abs=0.01)


@pytest.mark.parametrize('member, scale', [('heavy_20pct', 1 / 1.2), ('hover_thrust_error', 0.94)])
def test_thrust_scale_of_mass_and_hover_thrust_errors(tmp_path, member, scale):
    result = identify(load_flight(flown_bag(tmp_path, member)))
    thrust = result['thrust']
    assert thrust['thrust_scale'] == pytest.approx(scale, rel=0.01)
    low, high = thrust['thrust_scale_ci95']
    assert low <= thrust['thrust_scale'] <= high
    assert thrust['mass_error_equivalent'] == pytest.approx(1 / scale - 1, abs=0.015)


@pytest.fixture(scope='module')
def lag_bag(tmp_path_factory):
    return flown_bag(tmp_path_factory.mktemp('identify'), 'autopilot_lag')


def identify_cli(*args):
    return subprocess.run([sys.executable, '-m', 'quad_bringup.cli', 'identify', *map(str, args)],
                          capture_output=True, text=True, cwd=REPO_ROOT)


def test_cli_writes_a_profile_the_controller_flies(tmp_path, lag_bag):
    """The default base is the real-vehicle profile (what the bridge flies); it has margin on the lag found."""
    out = tmp_path / 'profile.yaml'
    done = identify_cli(lag_bag, '--out', out)
    assert done.returncode == 0, done.stderr
    assert 'roll : lag 0.1' in done.stdout and 'thrust: scale' in done.stdout
    assert 'margin (1.5x the response, tau + dead time 0.1' in done.stdout and '0.000 s, pid): ' in done.stdout
    assert "telemetry latency 0.000 s, 100 Hz, bursts up to 0.000 s (a simulator's bag" in done.stdout   # the bag's
    assert ': settled' in done.stdout
    written = yaml.safe_load(out.read_text())
    assert list(written) == ['position_controller']   # rcl takes nothing beside a node's ros__parameters
    params = written['position_controller']['ros__parameters']
    assert params['controller'] == 'pid' and params['attitude_lead_s'] == pytest.approx(0.15, rel=0.15)
    assert params['thrust_scale'] == pytest.approx(1.0, abs=0.01)
    assert params['drag_feedforward_per_s'] == 0.0   # the simulator flew it without drag: none measured
    assert params['kp_x'] == yaml.safe_load(resolve_config('config/control_real.yaml').read_text())[
        'position_controller']['ros__parameters']['kp_x']
    facts = read_identification(out.read_text())
    margin = facts['margin']
    assert margin['lag_s'] == pytest.approx(1.5 * facts['attitude_lead_s'], abs=1e-3)
    assert facts['window']['source'] == 'simulator (engaged throughout)' and facts['roll']['fit_r2'] > 0.9
    assert margin['latency_s'] == 0.0 and margin['oscillation_deg'] < 0.5


def test_cli_refuses_a_profile_without_margin(tmp_path, lag_bag):
    """control_fast behind 1.5x the identified lag (0.15 s) and 2x the latency oscillates: nothing is written."""
    out = tmp_path / 'fast.yaml'
    done = identify_cli(lag_bag, '--base', resolve_config('config/control_fast.yaml'), '--out', out,
                        '--latency-s', '0.05')
    assert done.returncode == 2, done.stdout
    assert not out.exists()
    message = done.stderr
    assert f'refused to write {out}' in message and 'se3' in message and 'control_fast.yaml' in message
    assert 's of attitude lag' in message and '0.100 s of telemetry latency' in message
    lag = float(message.split(' does not settle at ')[1].split(' s')[0])
    assert lag == pytest.approx(0.225, rel=0.15)
    tilt = float(message.split('(tilt ')[1].split(' deg')[0])
    oscillation = float(message.split('oscillation ')[1].split(' deg')[0])
    assert tilt > 20.0 and oscillation > 10.0
    assert 'NOT settled' in done.stdout


def test_soften_writes_the_base_softened_until_it_settles_and_says_by_how_much(tmp_path, lag_bag):
    """A pid base with kp 6 on x and y does not settle behind 1.5x the identified lag; with --soften its horizontal kp
    and ki are scaled down in steps until the margin check settles, and the profile written holds those gains."""
    base = yaml.safe_load(resolve_config('config/control_real.yaml').read_text())
    params = base['position_controller']['ros__parameters']
    params.update(kp_x=6.0, kp_y=6.0)
    base_file = tmp_path / 'stiff.yaml'
    base_file.write_text(yaml.safe_dump(base))
    out = tmp_path / 'soft.yaml'
    refused = identify_cli(lag_bag, '--base', base_file, '--out', out, '--latency-s', '0.05')
    assert refused.returncode == 2 and not out.exists()
    assert refused.stderr.rstrip().endswith(', or --soften'), refused.stderr
    done = identify_cli(lag_bag, '--base', base_file, '--out', out, '--latency-s', '0.05', '--soften')
    assert done.returncode == 0, done.stderr
    line = next(line for line in done.stdout.splitlines() if line.startswith('softened: '))
    factor = float(line.split(' x')[1].split()[0])
    assert 0.5 <= factor < 1.0, line
    assert ': settled' in next(line for line in done.stdout.splitlines() if line.startswith('margin ('))
    written = yaml.safe_load(out.read_text())['position_controller']['ros__parameters']
    assert (written['kp_x'], written['kp_y']) == (round(6.0 * factor, 4),) * 2
    assert (written['ki_x'], written['ki_y']) == (round(params['ki_x'] * factor, 4), round(params['ki_y'] * factor, 4))
    assert (written['kp_z'], written['kd_x']) == (params['kp_z'], params['kd_x'])     # the rest as the base has it
    assert read_identification(out.read_text())['softened'] == factor


def test_soften_refuses_a_base_that_half_its_gains_do_not_settle_saying_so(tmp_path, lag_bag):
    """control_fast (se3, kd 11) oscillates behind the margin's lag whatever its kp: refused, naming the factor."""
    out = tmp_path / 'fast.yaml'
    done = identify_cli(lag_bag, '--base', resolve_config('config/control_fast.yaml'), '--out', out,
                        '--latency-s', '0.05', '--soften')
    assert done.returncode == 2 and not out.exists()
    assert 'control_fast.yaml, even with its horizontal kp and ki x0.5) does not settle' in done.stderr, done.stderr


def test_cli_refuses_a_bad_latency_by_name(lag_bag):
    done = identify_cli(lag_bag, '--latency-s', 'nan')
    assert done.returncode == 2 and '--latency-s nan refused' in done.stderr


def test_a_bag_without_commands_is_refused_by_name(tmp_path):
    from quad_bringup.recording.recorder import DEFAULT_TOPICS, BagRecorder
    bag = tmp_path / 'empty'
    recorder = BagRecorder(bag)
    recorder.add_topic('odom', DEFAULT_TOPICS['odom'])
    recorder.close()
    done = subprocess.run([sys.executable, '-m', 'quad_bringup.cli', 'identify', str(bag)],
                          capture_output=True, text=True, cwd=REPO_ROOT)
    assert done.returncode == 2 and 'quadflight identify:' in done.stderr and 'odom' in done.stderr


def test_the_written_profile_loads_in_a_node_started_with_params_file(tmp_path, lag_bag):
    """rcl refuses any key beside a node's ros__parameters ("Cannot have a value before ros__parameters"): the
    profile identify writes starts position_controller with --params-file and sets what identify found."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter_client import AsyncParameterClient

    from quad_common.ros.testing import isolated_domain
    out = tmp_path / 'profile.yaml'
    done = identify_cli(lag_bag, '--out', out)
    assert done.returncode == 0, done.stderr
    params = yaml.safe_load(out.read_text())['position_controller']['ros__parameters']
    with isolated_domain() as (domain, env):
        node_proc = subprocess.Popen([sys.executable, '-m', 'quad_control.position_controller_node', '--ros-args',
                                      '--params-file', str(out)], env=env, cwd=REPO_ROOT, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True)
        context = rclpy.Context()
        rclpy.init(context=context, domain_id=domain)
        try:
            node = rclpy.create_node('profile_check', context=context)
            client = AsyncParameterClient(node, 'position_controller')
            names = ['controller', 'attitude_lead_s', 'thrust_scale', 'kp_x']
            for _ in range(60):   # until it offers its parameters, or it exited (a params file rcl refused)
                if client.wait_for_services(timeout_sec=1.0) or node_proc.poll() is not None:
                    break
            assert node_proc.poll() is None, f'position_controller {_ended(node_proc)}'
            assert client.services_are_ready(), 'position_controller never offered its parameters'
            future = client.get_parameters(names)
            executor = SingleThreadedExecutor(context=context)
            executor.add_node(node)
            executor.spin_until_future_complete(future, timeout_sec=30.0)
            values = [v for v in (p.string_value or p.double_value for p in future.result().values)]
        finally:
            context.try_shutdown()
            node_proc.terminate()
            node_proc.wait(timeout=20)
    assert values == [params[n] for n in names]


def _ended(proc):
    if proc.poll() is None:
        return 'still running'
    return f'exited {proc.returncode}: {proc.stdout.read()[-2000:]}'


# --- the window in which the vehicle flew our setpoints ----------------------------------------

EPOCH_NS = 1_796_000_000 * 10**9   # a bridge flight is stamped with the wall clock
RECORD_DELAY_NS = 3_000_000       # a message reaches the recorder 3 ms after its stamp
GROUND_S = 4.0                    # before the hand-over: on the ground, the controller's output not flown
LANDING_S = 12.0                  # after it: the autopilot's AUTO.LAND and the ground, the controller still talking


def _bridge_bag(tmp_path, flown, window='engaged', engaged_through_landing=False):
    """The flight of `flown` (a closed_loop bag) as a bridge flight's bag: wall-clock stamps, GROUND_S on the ground
    before it and LANDING_S after it in which the controller commands 16-27 m/s^2 and +-8 deg that the vehicle,
    descending and then standing, never flies (a landing phase), and `window`: 'engaged' (vehicle/engaged
    true from the hand-over's start to its end), 'diagnostics' (the bridge's 1 Hz hand-over status) or None."""
    from quad_bringup.recording.recorder import DEFAULT_TOPICS, BagRecorder, open_bag_reader, typestore
    from quad_common import contract
    ts, T = typestore(), typestore().types
    reader, _ = open_bag_reader(flown)
    msgs = {'odom': [], 'cmd/attitude_thrust': []}
    try:
        for conn, t_ns, raw in reader.messages():
            msgs[conn.topic].append((t_ns, ts.deserialize_cdr(raw, conn.msgtype)))
    finally:
        reader.close()
    t_first = min(t for t, _ in msgs['odom'])
    t_last = max(t for t, _ in msgs['odom'])
    shift = EPOCH_NS + int(GROUND_S * 1e9) - t_first
    bag = tmp_path / f'bridge-{window}-{engaged_through_landing}'
    out = BagRecorder(bag)
    for topic in ('odom', 'cmd/attitude_thrust', contract.ENGAGED, contract.DIAGNOSTICS):
        out.add_topic(topic, DEFAULT_TOPICS[topic])

    def write(topic, stamp_ns, msg, msgtype):
        if hasattr(msg, 'header'):
            msg.header.stamp = T['builtin_interfaces/msg/Time'](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
        out.write(topic, stamp_ns + RECORD_DELAY_NS, ts.serialize_cdr(msg, msgtype))

    first_odom, first_cmd = msgs['odom'][0][1], msgs['cmd/attitude_thrust'][0][1]
    last_odom = msgs['odom'][-1][1]
    period_ns = 10_000_000
    for k in range(int(GROUND_S * 100)):   # on the ground, level, the controller asking for a little thrust
        t = EPOCH_NS + k * period_ns
        write('odom', t, first_odom, 'nav_msgs/msg/Odometry')
        write('cmd/attitude_thrust', t, first_cmd, 'sensor_msgs/msg/Imu')
    for topic, kind in (('odom', 'nav_msgs/msg/Odometry'), ('cmd/attitude_thrust', 'sensor_msgs/msg/Imu')):
        for t, msg in msgs[topic]:
            write(topic, t + shift, msg, kind)
    end_ns = t_last + shift
    z0 = last_odom.pose.pose.position.z
    for k in range(1, int(LANDING_S * 100)):   # AUTO.LAND at 0.5 m/s to the ground, then standing there
        t = end_ns + k * period_ns
        odom = ts.deserialize_cdr(ts.serialize_cdr(last_odom, 'nav_msgs/msg/Odometry'), 'nav_msgs/msg/Odometry')
        odom.pose.pose.orientation = T['geometry_msgs/msg/Quaternion'](0.0, 0.0, 0.0, 1.0)
        odom.pose.pose.position.z = max(z0 - 0.5 * k * 0.01, 0.0)
        odom.twist.twist.linear = T['geometry_msgs/msg/Vector3'](0.0, 0.0, -0.5 if odom.pose.pose.position.z else 0.0)
        odom.twist.twist.angular = T['geometry_msgs/msg/Vector3'](0.0, 0.0, 0.0)
        write('odom', t, odom, 'nav_msgs/msg/Odometry')
        cmd = ts.deserialize_cdr(ts.serialize_cdr(first_cmd, 'sensor_msgs/msg/Imu'), 'sensor_msgs/msg/Imu')
        roll = np.radians(8.0) * np.sin(2 * np.pi * 0.4 * k * 0.01)
        cmd.orientation = T["geometry_msgs/msg/Quaternion"](float(np.sin(roll / 2)), 0.0, 0.0,
                                                            float(np.cos(roll / 2)))
        cmd.linear_acceleration.z = 16.0 + 11.0 * (k / (LANDING_S * 100))
        write('cmd/attitude_thrust', t, cmd, 'sensor_msgs/msg/Imu')
    start_ns = EPOCH_NS + int(GROUND_S * 1e9)
    if window == 'engaged':
        for t, on in ((EPOCH_NS, False), (start_ns, True), (end_ns, False)):
            if on or not engaged_through_landing or t == EPOCH_NS:
                write(contract.ENGAGED, t, T['std_msgs/msg/Bool'](data=on), 'std_msgs/msg/Bool')
    elif window == 'diagnostics':
        KeyValue, Status = T['diagnostic_msgs/msg/KeyValue'], T['diagnostic_msgs/msg/DiagnosticStatus']
        for t in range(EPOCH_NS + 500_000_000, end_ns + int(LANDING_S * 1e9), 1_000_000_000):
            phase = 'active' if start_ns <= t <= end_ns else 'idle'
            status = Status(level=0, name='mavlink_bridge: setpoints', message='', hardware_id='',
                            values=[KeyValue(key='handover', value=phase)])
            array = T['diagnostic_msgs/msg/DiagnosticArray'](header=first_odom.header, status=[status])
            write(contract.DIAGNOSTICS, t, array, 'diagnostic_msgs/msg/DiagnosticArray')
    out.close()
    return bag, (start_ns - EPOCH_NS) / 1e9, (end_ns - EPOCH_NS) / 1e9


@pytest.mark.parametrize('window', ['engaged', 'diagnostics'])
def test_a_bridge_bag_is_scored_only_where_the_vehicle_flew_our_setpoints(tmp_path, lag_bag, window):
    """The flight between the ground and the autopilot's landing, cut by vehicle/engaged (or, without it, the
    bridge's hand-over diagnostics): the lag of the member's own loop within 15 %, thrust scale 1, fits that
    hold; the landing phase never enters the window."""
    bag, start_s, end_s = _bridge_bag(tmp_path, lag_bag, window)
    truth_s = attitude_mean_delay_s(load_vehicle(CRAZYFLIE, plant='autopilot_lag'))
    result = identify(load_flight(bag))
    w = result['window']
    print(window, w, {a: (result[a]['lag_s'], result[a]['fit_r2']) for a in ('roll', 'pitch')}, result['thrust'])
    assert w['source'] == ('vehicle/engaged' if window == 'engaged' else "the bridge's hand-over diagnostics")
    epoch_s = EPOCH_NS / 1e9
    assert start_s - 1e-3 <= w['start_s'] - epoch_s and w['end_s'] - epoch_s <= end_s + 0.01
    assert w['duration_s'] > (end_s - start_s) - (2.5 if window == 'diagnostics' else 0.5)
    for axis in ('roll', 'pitch'):
        assert result[axis]['lag_s'] == pytest.approx(truth_s, rel=0.15)
    assert result['thrust_scale'] == pytest.approx(1.0, abs=0.01)
    assert quality_refusal(result) is None


def test_fits_that_scored_the_landing_are_refused_saying_why(tmp_path, lag_bag):
    """vehicle/engaged true through the landing (a window that is wrong): the fits do not hold, and the CLI says
    so in one line with the manoeuvre to fly, writing nothing."""
    bag, *_ = _bridge_bag(tmp_path, lag_bag, 'engaged', engaged_through_landing=True)
    result = identify(load_flight(bag))
    reason = quality_refusal(result)
    print(reason, {a: (result[a]['lag_s'], result[a]['fit_r2']) for a in ('roll', 'pitch')}, result['thrust'])
    assert reason is not None and 'fly a manoeuvre' in reason
    out = tmp_path / 'profile.yaml'
    done = identify_cli(bag, '--out', out)
    assert done.returncode == 2 and not out.exists()
    assert done.stderr.count('\n') == 1 and f'refused to write {out}: ' in done.stderr and reason in done.stderr


def test_a_bridge_bag_that_cannot_be_windowed_is_refused(tmp_path, lag_bag):
    bag, *_ = _bridge_bag(tmp_path, lag_bag, window=None)
    done = identify_cli(bag)
    assert done.returncode == 2, done.stdout
    assert 'does not say when the vehicle flew our setpoints' in done.stderr and 'vehicle/engaged' in done.stderr


@pytest.fixture(scope='module')
def feedforward_bag(tmp_path_factory):
    """control_se3 (body rates fed forward) flying the figure8 at 2 m/s on autopilot_so3 (a PX4-like cascade that
    follows those rates): the commanded attitude is tracked within a sample, its 0.154 s lag does not show."""
    from quad_bringup.offline.closed_loop import load_control_profile
    from quad_trajectory.mission import load_mission
    bag = tmp_path_factory.mktemp('feedforward') / 'bag'
    controller, gains = load_control_profile(resolve_config('config/control_se3.yaml'))
    figure8 = resolve_config('config/missions/figure8.yaml')
    assert load_mission(figure8).options.v_max_mps is not None
    fly_offline(figure8, LoopOptions(controller=controller, gains=gains, speed_mps=2.0, plant='autopilot_so3',
                                     plan_overrides={'time_allocation': 'limits'}, bag_dir=bag))
    return bag


def test_a_fit_at_the_edge_of_its_search_range_is_refused_saying_what_to_fly(tmp_path, feedforward_bag):
    out = tmp_path / 'edge.yaml'
    done = identify_cli(feedforward_bag, '--base', resolve_config('config/control_se3.yaml'), '--out', out)
    assert done.returncode == 2 and not out.exists(), done.stdout
    assert 'roll : lag 0.005 s (95 % 0.005-0.005' in done.stdout   # what it measured is still shown
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and 'the roll fit (lag 0.005 s = tau 0.005 s + dead time 0.000 s) sits at the edge' in \
        lines[0] and '--controller pd' in lines[0]


def test_the_profile_feeds_forward_the_drag_measured_and_none_that_is_not():
    base = {'position_controller': {'ros__parameters': {'controller': 'pid', 'drag_feedforward_per_s': 0.7}}}
    result = {'attitude_lead_s': 0.25, 'thrust_scale': 1.02,
              'drag': {'rotor_drag_xy': 1e-4, 'rotor_drag_xy_ci95': (8e-5, 1.2e-4),
                       'deceleration_per_mps_at_hover': 0.9512}}
    params = profile(result, base)['position_controller']['ros__parameters']
    assert params['drag_feedforward_per_s'] == 0.951 and params['controller'] == 'pid'
    unsure = {**result, 'drag': {**result['drag'], 'rotor_drag_xy_ci95': (-1e-5, 2e-4)}}
    assert profile(unsure, base)['position_controller']['ros__parameters']['drag_feedforward_per_s'] == 0.0
    no_drag = {k: v for k, v in result.items() if k != 'drag'}   # the base's value stays
    assert profile(no_drag, base)['position_controller']['ros__parameters']['drag_feedforward_per_s'] == 0.7


def test_a_collapsed_interval_is_refused(feedforward_bag):
    result = identify(load_flight(feedforward_bag))
    assert result['roll']['lag_ci95_s'][1] - result['roll']['lag_ci95_s'][0] < 1e-3
    inside = {**result, 'roll': {**result['roll'], 'tau_s': 0.05, 'lag_s': 0.05}}   # off the edge, same parts
    assert 'collapsed 95 % interval' in quality_refusal(inside)


def test_the_vehicle_model_flies_with_the_response_identified(tmp_path, lag_bag):
    """identify -> vehicle YAML -> the offline loop and a sweep's vehicles: accept it, and a flight of the model
    identifies the same lag and thrust scale again (the model is the vehicle identify measured)."""
    from quad_bringup.experiments.runs import vehicle_entry
    out, model = tmp_path / 'profile.yaml', tmp_path / 'model.yaml'
    done = identify_cli(lag_bag, '--out', out, '--model-out', model, '--vehicle', CRAZYFLIE)
    assert done.returncode == 0, done.stderr
    assert f'vehicle model: {model} (attitude_loop lag 0.1' in done.stdout
    first = read_identification(out.read_text())
    vehicle = load_vehicle(model)
    assert vehicle.attitude_loop.type == 'lag' and vehicle.name == 'crazyflie_identified'
    assert vehicle.attitude_loop.time_constant_s == pytest.approx(first['attitude_lead_s'], abs=1e-3)
    assert vehicle.inertia_kgm2 == pytest.approx(load_vehicle(CRAZYFLIE).inertia_kgm2, rel=1e-9)
    assert vehicle_entry(str(model), 'vehicles[0]')[1] == str(model)
    assert vehicle.extra['aerodynamics']['rotor_drag_xy'] == 0.0   # the simulator flew it without drag
    assert abs(first['drag']['deceleration_per_mps_at_hover']) < 0.02
    bag = tmp_path / 'twin-bag'
    metrics = fly_offline(MAZE, LoopOptions(speed_mps=1.0, vehicle_path=str(model), bag_dir=bag))
    assert metrics['completed'] and not metrics.get('stopped')
    again = identify(load_flight(bag))
    assert again['attitude_lead_s'] == pytest.approx(first['attitude_lead_s'], rel=0.1)
    assert again['thrust_scale'] == pytest.approx(first['thrust_scale'], abs=0.01)


def test_model_out_replaces_only_a_file_identify_wrote(tmp_path, lag_bag):
    model = tmp_path / 'mine.yaml'
    model.write_text('name: mine\n')
    done = identify_cli(lag_bag, '--out', tmp_path / 'p.yaml', '--model-out', model)
    assert done.returncode == 2 and 'not written by quadflight identify' in done.stderr
    assert model.read_text() == 'name: mine\n' and not (tmp_path / 'p.yaml').exists()


def test_the_margin_checks_telemetry_is_the_bags(tmp_path, lag_bag):
    """A simulator's bag: lockstep, 100 Hz, no bursts. A vehicle's bag (wall clock): the median record - stamp
    delay (at least ArduCopter's 0.05 s: the bridge bag's 3 ms is not the vehicle's estimator delay), the
    record-time gaps as bursts; --latency-s replaces the latency and the line says what the bag had."""
    from quad_bringup.analysis.metrics import Flight
    from quad_bringup.offline.stability import MEASURED_LATENCY_S, Telemetry
    sim = Telemetry.of_flight(load_flight(lag_bag))
    assert (sim.latency_s, sim.burst_s, round(sim.rate_hz)) == (0.0, 0.0, 100) and 'simulator' in sim.source
    bridge, *_ = _bridge_bag(tmp_path, lag_bag)
    vehicle = Telemetry.of_flight(load_flight(bridge))
    assert vehicle.latency_s == MEASURED_LATENCY_S and vehicle.burst_s == pytest.approx(0.0, abs=1e-6)
    given = Telemetry.of_flight(load_flight(bridge), 0.08)
    assert given.latency_s == 0.08 and 'latency 0.080 s as given (the bag: 0.050 s)' in given.source
    n = 400   # 100 Hz stamps, released 0.12 s later in bursts of four (every 40 ms)
    stamps_ns = EPOCH_NS + np.arange(n) * 10_000_000
    record_ns = EPOCH_NS + 120_000_000 + (np.arange(n) // 4 * 4 + 3) * 10_000_000
    bursty = Flight(odom_t=stamps_ns * 1e-9, position=np.zeros((n, 3)), velocity=np.zeros((n, 3)),
                    euler=np.zeros((n, 3)), odom_record_ns=record_ns)
    seen = Telemetry.of_flight(bursty)
    assert seen.latency_s == pytest.approx(0.135, abs=0.006) and seen.burst_s == pytest.approx(0.03, abs=1e-3)


def _member_hold(plant_fields, controller, gains):
    """stability's hold (20 s from a (0.5, 0, 0.3) m offset) flown on the Crazyflie with plant_fields, without
    the check's model: the plant's own loop, odometry every tick."""
    from quad_bringup.offline.stability import HOLD_ALTITUDE_M, hold_of
    from quad_common import rotations
    from quad_common.types import Reference
    from quad_control.position import Limits, PositionController
    from quad_sim.simulator import Simulator
    nominal = load_vehicle(CRAZYFLIE)
    target = np.array([0.0, 0.0, HOLD_ALTITUDE_M])
    sim = Simulator(load_vehicle(CRAZYFLIE, plant=plant_fields), physics_rate_hz=1000.0,
                    initial_position=target + [0.5, 0.0, 0.3], setpoint_timeout_s=1e6)
    control = PositionController(controller, gains, nominal, Limits.of(nominal))
    ref = Reference(position=target, velocity=np.zeros(3), acceleration=np.zeros(3), jerk=np.zeros(3), yaw=0.0,
                    yaw_rate=0.0)
    positions, euler = [], []
    for k in range(2000):
        setpoint, _ = control.update(sim.odometry_state(), ref, 0.01 if k else 0.0)
        sim.set_setpoint(setpoint)
        sim.advance(0.01)
        positions.append(sim.state.position)
        euler.append(rotations.to_euler(sim.state.quaternion)[:2])
    return hold_of(0.0, 0.0, 0.0, positions, euler, target, 0.01)


@pytest.mark.parametrize('stiff, settles', [(False, True), (True, False)])
def test_the_margin_verdict_matches_a_cascade_1_5x_slower(tmp_path, stiff, settles):
    """autopilot_so3 (a PX4-like angle-P 6.5 / rate-P 60 cascade: not the check's first order plus dead time),
    identified from a pd flight: the check's verdict at 1.5x equals the member's own with angle_p and rate_p / 1.5
    (its response 1.5x slower): control_se3 settles on both, se3 with kp 40 / kd 13 oscillates on both."""
    from quad_bringup.offline.closed_loop import load_control_profile
    from quad_bringup.offline.stability import Telemetry, margin_hold_identified
    flight = load_flight(flown_bag(tmp_path, 'autopilot_so3'))
    result = identify(flight)
    assert result['attitude_lead_s'] == pytest.approx(0.154, rel=0.05)
    controller, gains = load_control_profile(resolve_config('config/control_se3.yaml'))
    gains.attitude_lead_s = result['attitude_lead_s']
    if stiff:
        gains.kp[:2], gains.kd[:2] = 40.0, 13.0
    check = margin_hold_identified(CRAZYFLIE, controller, gains, result, Telemetry.of_flight(flight))
    slower = {'attitude_loop': {'type': 'so3_pd', 'angle_p': [6.5 / 1.5, 6.5 / 1.5, 2.8],
                                'rate_p': [60.0 / 1.5, 60.0 / 1.5, 30.0]}}
    member = _member_hold(slower, controller, gains)
    assert check.settled == member.settled == settles, (check.describe(), member.describe())
    if not settles:   # the check's dead time (1.5 periods) flies as one whole period: 0.57 deg, the member 5 deg
        assert check.oscillation_deg > 0.5 and member.oscillation_deg > 5.0


def test_a_flight_too_short_for_the_lag_interval_is_refused_naming_the_flight_to_fly(tmp_path):
    """The README's 4 s maze at 2 m/s: a good fit, but its command moves for less than the interval's 3 parts of
    2 s."""
    bag = tmp_path / 'maze-2mps'
    fly_offline(MAZE, LoopOptions(speed_mps=2.0, bag_dir=bag))
    result = identify(load_flight(bag))
    assert result['roll']['fit_r2'] > 0.99 and result['roll']['blocks'] < 3
    reason = quality_refusal(result)
    assert reason.startswith('the flight is too short to measure the roll lag: its roll command moves for '), reason
    assert 'the interval needs 3 parts of 2 s (6 s)' in reason
    assert reason.endswith('quadflight fly config/missions/figure8.yaml --controller pd') and 'nan' not in reason


def test_a_flight_whose_parts_barely_move_is_refused_as_too_gentle():
    axis = {'tau_s': 0.09, 'delay_s': 0.0, 'lag_s': 0.09, 'lag_ci95_s': [float('nan')] * 2, 'blocks': 2,
            'parts': 6, 'moving_s': 20.0, 'fit_r2': 1.0}
    result = {'roll': axis, 'pitch': axis, 'thrust': {'thrust_scale': 1.0, 'thrust_scale_ci95': [0.999, 1.001]}}
    reason = quality_refusal(result)
    assert reason.startswith('the flight is too gentle to measure the roll lag: 2 of the 6 parts of its 20.0 s of '
                             'roll motion command 0.75 deg or more of roll (std), 3 are needed: '), reason


def test_the_lag_parts_cut_where_the_command_moves_however_long_the_hover_around_it():
    """A part that is mostly hover with a little motion at its end fits a guess (on an emulated PX4 flight under
    load, 0.28 s where the rest fit 0.17-0.19 s, and identify refused a right 0.183 s), and parts cut from the whole
    window grow with the hover until too few move: the parts cut the span where the command moves, so a hover before
    or after the plan, as long as the user waited, changes none of them."""
    from quad_bringup.analysis import identify as idf
    motion = np.deg2rad(5.0) * np.cos(np.linspace(0.0, 12 * np.pi, 1200))   # moving from its first to last sample
    expected = np.split(motion, idf.BLOCKS)                                  # 12 s: 6 parts of 2 s
    for before, after in ((0, 0), (300, 400), (7000, 0), (0, 7000)):
        u = np.concatenate([np.zeros(before), motion, np.zeros(after)])
        parts = idf._parts(u, u)
        assert len(parts) == len(expected), (before, after)
        assert all(np.array_equal(p, e) for (p, _), e in zip(parts, expected)), (before, after)
    short = idf._parts(np.concatenate([np.zeros(3000), motion[:700]]), np.zeros(3700))   # 7 s: 3 parts of 2.33 s
    assert [len(p) for p, _ in short] == [233, 234, 233]


def test_a_long_hover_before_the_plan_changes_neither_the_lag_nor_its_interval(tmp_path):
    """The same maze flown after 5 s and after 60 s of hover: parts cut from the whole window grew with the hover
    (1/6 of a 68 s window is longer than the maze's 7.7 s of motion) and identify refused the longer one."""
    fits = {}
    for hover_s in (5.0, 60.0):
        bag = tmp_path / f'hover{hover_s:g}'
        fly_offline(MAZE, LoopOptions(speed_mps=1.0, plant='autopilot_lag', start_delay_s=hover_s, bag_dir=bag))
        result = identify(load_flight(bag))
        assert result['window']['duration_s'] > hover_s and quality_refusal(result) is None, quality_refusal(result)
        fits[hover_s] = [x for a in ('roll', 'pitch') for x in (result[a]['lag_s'], *result[a]['lag_ci95_s'])]
        assert result['roll']['blocks'] >= 3 and result['pitch']['blocks'] >= 3
    assert fits[5.0] == pytest.approx(fits[60.0], abs=1e-4), fits   # 0.1 ms: the flights differ by 2 us
