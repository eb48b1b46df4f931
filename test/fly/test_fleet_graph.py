"""Graph tests: a fleet through the ROS graph (quad_bringup.running.fleet_graph): one sim_node for every vehicle under
one /clock, each vehicle's trajectory_node and position_controller under its namespace, the recorder's bag."""

import json
import signal
import subprocess
import threading
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import rclpy
import yaml
from rosbags.rosbag2 import Reader
from rosgraph_msgs.msg import Clock

from quad_bringup.running import fleet_graph
from quad_common import contract
from quad_common.domains import isolated_domain
from quad_common.ros import lockstep
from quad_trajectory.fleet import load_fleet, plan_fleet

ROOT = Path(__file__).resolve().parents[2]
QUADFLIGHT = str(ROOT / 'quadflight')
TIMEOUT_S = 540     # a hang guard, far above a loaded run
HOLD_PROBE = 'probe'


def two_abreast(tmp_path) -> Path:
    """Two Crazyflies 1 m apart flying the same 1.5 m leg side by side."""
    path = tmp_path / 'abreast.yaml'
    path.write_text(f'name: abreast\nvehicle: {ROOT / "config/vehicles/crazyflie.yaml"}\n'
                    'waypoints: [[0.0, 0.0, 1.0], [1.5, 0.0, 1.0]]\nyaw: 0.0\n'
                    'trajectory: {method: minsnap, speed: 0.5, time_allocation: sqrt}\n'
                    'vehicles:\n  - {name: cf1, offset: [0.0, -0.5, 0.0]}\n  - {name: cf2, offset: [0.0, 0.5, 0.0]}\n')
    return path


@contextmanager
def flying_until(run, sim_time_s: float, hold: bool = False):
    """Starts the run's processes in an isolated domain and returns from __enter__ once its /clock reached
    sim_time_s (a probe node), giving {'deadline': the hang guard's}; stops every process at the end (their exit
    codes in its 'codes'). hold: the probe is the run's lockstep follower HOLD_PROBE (prepare(followers=...)) and
    acknowledges no step after sim_time_s until the body calls flight['release'](), so the simulator waits there (at
    most lockstep.FOLLOWER_LAG_STEPS odometry periods later) whatever the load: the body acts at that sim time."""
    sim_times, newest, flight = [], [], {}
    released = threading.Event()
    with isolated_domain() as (domain, env):
        ctx = rclpy.Context()
        rclpy.init(context=ctx, domain_id=domain)
        probe = rclpy.create_node(HOLD_PROBE, context=ctx)
        acks = probe.create_publisher(Clock, lockstep.ack_topic(HOLD_PROBE), lockstep.ACK) if hold else None

        def on_clock(msg):
            t_s = msg.clock.sec + msg.clock.nanosec * 1e-9
            sim_times.append(t_s)
            newest[:] = [msg]
            if acks is not None and (t_s <= sim_time_s or released.is_set()):
                acks.publish(msg)   # taken: the stamp acknowledged

        probe.create_subscription(Clock, contract.CLOCK, on_clock, lockstep.PACED if hold else 10)
        executor = rclpy.executors.SingleThreadedExecutor(context=ctx)
        executor.add_node(probe)
        try:
            run.start(env)
            deadline = time.monotonic() + TIMEOUT_S
            while not (sim_times and sim_times[-1] >= sim_time_s):
                assert time.monotonic() < deadline, f'the fleet never reached t = {sim_time_s} s'
                assert run.nodes[0].exit_code() is None, run.nodes[0].log_tail()
                executor.spin_once(timeout_sec=0.1)
            flight['deadline'] = deadline
            if hold:
                def release():   # the probe acknowledges every step from now on, until the run has stopped
                    released.set()
                    acks.publish(newest[0])   # the step the simulator waits at: taken

                flight['release'] = release
                threading.Thread(target=_spin_until_shutdown, args=(executor,), daemon=True).start()
                try:
                    yield flight
                finally:
                    release()
            else:
                executor.remove_node(probe)
                probe.destroy_node()
                yield flight
        finally:
            flight['codes'] = run.stop(log=lambda *_: None)
            executor.shutdown()
            rclpy.shutdown(context=ctx)


def _spin_until_shutdown(executor):
    try:
        executor.spin()
    except Exception:   # the context shut down under it
        pass


def test_a_formation_of_four_flies_through_the_graph_and_each_vehicle_completes(tmp_path, ros_env):
    out = tmp_path / 'run'
    done = subprocess.run([QUADFLIGHT, 'fleet', str(ROOT / 'config/missions/fleets/formation4.yaml'), '--graph',
                           '--out', str(out), '--no-figures'],
                          env=ros_env, capture_output=True, text=True, timeout=TIMEOUT_S)
    assert done.returncode == 0, done.stdout + done.stderr
    content = json.loads((out / 'fleet.json').read_text())
    assert set(content['metrics']) == {'cf1', 'cf2', 'cf3', 'cf4'}
    for name, m in content['metrics'].items():
        assert m['completed'] and not m['collided'], (name, m)
        assert m['rmse_m'] < 0.03, (name, m['rmse_m'])
    assert content['collisions'] == []
    for name, m in content['metrics'].items():   # each vehicle's report: the seed's table of its part of the bag
        report = json.loads((out / 'vehicles' / name / 'metrics.json').read_text())
        assert report['rmse_m'] == m['rmse_m'] and report['completion_rule']['source'] == 'vehicle crazyflie'
        assert (out / 'vehicles' / name / 'report.md').is_file()
    assert 0.7 < content['flown_minimum_separation']['distance_m'] < 0.9     # the 0.8 m square holds
    with Reader(out / 'bag') as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    # every vehicle's odometry under its namespace, one per step of the one /clock: nothing lost (the report's record
    # check: distinct stamps against the steps sim_node says it published; step 0 may be re-published at start-up)
    for name in content['metrics']:
        record = json.loads((out / 'vehicles' / name / 'metrics.json').read_text())['record']
        assert record['complete'] and record['gaps'] == [], (name, record)
        assert record['odom_recorded'] == record['/clock_recorded'] == record['steps_published'] > 1000, record
        assert counts[f'/{name}/{contract.SETPOINT}'] > 0.9 * record['steps_published']
    # cf4 flew pid, the others pd (each controller its own parameters)
    params = yaml.safe_load((out / 'params.yaml').read_text())
    assert [params[f'/{n}/position_controller']['ros__parameters']['controller'] for n in ('cf1', 'cf4')] == \
        ['pd', 'pid']


def test_a_vehicle_whose_controller_dies_lands_and_the_other_completes(tmp_path):
    """One process per node, as launch_ros starts them; cf1's controller is killed at t = 2 s: its simulator's
    failsafe lands it, cf2 flies its plan to the end at full speed."""
    plan = plan_fleet(load_fleet(two_abreast(tmp_path)))
    run = fleet_graph.prepare(plan, tmp_path / 'run', hosted=False, followers=(HOLD_PROBE,))
    victim = next(p for p in run.nodes if 'cf1_position_controller' in p.log_path.name)
    with flying_until(run, 2.0, hold=True) as flight:   # the simulator waits at ~2 s until the kill is done
        victim.signal_group(signal.SIGKILL)
        flight['release']()
        run.await_end(flight['deadline'], expected_dead=[victim])
    result = fleet_graph.fleet_run(run.bag, plan)
    cf1, cf2 = result.metrics['cf1'], result.metrics['cf2']
    assert cf2['completed'] and cf2['rmse_m'] < 0.03, cf2
    assert not cf1['completed']
    assert result.positions['cf1'][-1, 2] < 0.1, result.positions['cf1'][-1]     # landed by its failsafe
    from quad_bringup.analysis.report import load_flight, load_flights
    alone = {n: load_flight(run.bag, namespace=n) for n in ('cf1', 'cf2')}
    # where it was when its controller died (its last setpoint): the simulator waited for the probe at most
    # FOLLOWER_LAG_STEPS odometry periods after t = 2 s, whatever the load, so mid-leg
    died_s = alone['cf1'].cmd_t[-1]
    at_death = np.array([np.interp(died_s, alone['cf1'].odom_t, alone['cf1'].position[:, a]) for a in (0, 1)])
    period_s = float(np.median(np.diff(alone['cf1'].odom_t)))
    assert 1.99 <= died_s <= 2.0 + (lockstep.FOLLOWER_LAG_STEPS + 2) * period_s, (died_s, period_s)
    assert at_death[0] < 1.2, at_death    # before the leg's end (1.5 m)
    assert np.linalg.norm(result.positions['cf1'][-1, :2] - at_death) < 0.2, (result.positions['cf1'][-1], at_death)
    assert result.collisions == []
    assert any(name == contract.SIM_FAILSAFE for _, name, _ in alone['cf1'].errors)
    assert not any(name == contract.SIM_FAILSAFE for _, name, _ in alone['cf2'].errors)
    for name, flight in load_flights(run.bag, ['cf1', 'cf2']).items():   # one read of the bag: the same flights
        for field in ('odom_t', 'position', 'cmd_t', 'cmd_euler', 'clock_stamps_ns'):
            assert np.array_equal(getattr(flight, field), getattr(alone[name], field)), (name, field)
        assert flight.errors == alone[name].errors and flight.sim_published == alone[name].sim_published
    assert not np.array_equal(alone['cf1'].position[-1], alone['cf2'].position[-1])
    log = (run.out_dir / 'logs' / 'sim_node.log').read_text()
    assert 'cf1: no setpoint' in log and 'cf2: no setpoint' not in log


def test_the_simulator_hosted_with_the_vehicles_stops_on_sigint_and_loses_nothing(tmp_path):
    """The default layout: sim_node, the recorder and every vehicle's nodes in one node_host process. SIGINT at
    t ~1 s (the probe holds the lockstep there, whatever the load: the whole flight takes well under a second of wall
    time): the simulator (not rclpy) takes it, publishes its final diagnostics, the recorder takes what is queued and
    closes the bag, and the process exits 0; every step it published is in the bag, for each vehicle."""
    plan = plan_fleet(load_fleet(two_abreast(tmp_path)))
    run = fleet_graph.prepare(plan, tmp_path / 'run', followers=(HOLD_PROBE,))
    assert [p.name for p in run.processes] == ['node_host'] and run.recorder is None, run.processes
    assert run.nodes[0].argv[:2] == ['sim_node', 'recorder'], run.nodes[0].argv
    host = run.nodes[0]
    with flying_until(run, 1.0, hold=True) as flight:
        host.signal_group(signal.SIGINT)
        flight['release']()   # the simulator's drain waits for every follower to take its last step
        while host.exit_code() is None:
            assert time.monotonic() < flight['deadline'], 'node_host did not stop after SIGINT'
            time.sleep(0.05)   # polling a child's exit (no event to await but waitpid)
    codes = flight['codes']
    assert host.exit_code() == 0 and codes == {'node_host': 0}, (codes, host.log_tail())
    log = host.log_path.read_text()
    assert 'lockstep: stepped' in log and 'may miss the last steps' not in log and 'bag closed' in log, log
    result = fleet_graph.fleet_run(run.bag, plan)
    for name, m in result.metrics.items():
        assert m['record']['complete'] and m['record']['odom_recorded'] == m['record']['steps_published'] > 100, \
            (name, m['record'])
        assert not m['completed']        # stopped mid-flight


def test_sim_node_refuses_a_fleet_whose_arrays_do_not_match_naming_the_field(ros_env):
    done = subprocess.run(
        [str(ROOT / '.venv/bin/python'), '-m', 'quad_sim.sim_node', '--ros-args', '-p',
         'vehicle_names:=[cf1, cf2]', '-p', 'initial_positions:=[0.0, 0.0, 1.0]'],
        env=ros_env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stdout + done.stderr
    assert 'initial_positions = [0.0, 0.0, 1.0] refused: needs 6 values' in done.stderr
    done = subprocess.run(
        [str(ROOT / '.venv/bin/python'), '-m', 'quad_sim.sim_node', '--ros-args', '-p', 'vehicle_names:=[cf1, cf1]',
         '-p', 'initial_positions:=[0.0, 0.0, 1.0, 1.0, 0.0, 1.0]'],
        env=ros_env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "vehicle_names: 'cf1' refused: named twice" in done.stderr, done.stderr


def test_node_host_takes_fly_s_nodes_without_a_namespace():
    from quad_bringup.running.node_host import parse_nodes

    nodes, ros_args = parse_nodes(['trajectory_node', 'sim_node', 'position_controller', '--ros-args', '-p', 'a:=1'])
    assert nodes == [('trajectory_node', ''), ('sim_node', ''), ('position_controller', '')]
    assert ros_args == ['--ros-args', '-p', 'a:=1']
    assert parse_nodes(['position_controller', 'position_controller@cf1'])[0] == [
        ('position_controller', ''), ('position_controller', 'cf1')]
    assert parse_nodes(['recorder', 'sim_node'])[0] == [('recorder', ''), ('sim_node', '')]   # fly's recorder


def test_node_host_refuses_an_unknown_node_and_a_node_given_twice(ros_env):
    for args, text in ((['sim_node@cf1'], "node 'sim_node@cf1' refused"),
                       (['recorder@cf1', 'sim_node'], "node 'recorder@cf1' refused"),
                       (['recorder', 'position_controller'], "node 'recorder' refused without sim_node"),
                       (['position_controller@'], "node 'position_controller@' refused"),
                       (['planner'], "node 'planner' refused"),
                       (['position_controller', 'position_controller'], 'given twice'),
                       (['position_controller@cf1', 'position_controller@cf1'], 'given twice')):
        done = subprocess.run([str(ROOT / '.venv/bin/python'), '-m', 'quad_bringup.running.node_host', *args],
                              env=ros_env, capture_output=True, text=True, timeout=120)
        assert done.returncode == 2 and text in done.stderr, done.stderr


def test_flown_contacts_finds_a_crossing_between_samples():
    t = np.array([0.0, 0.01])
    a = np.array([[0.0, -0.1, 1.0], [0.0, 0.1, 1.0]])      # they swap sides between the samples
    b = np.array([[0.0, 0.1, 1.0], [0.0, -0.1, 1.0]])
    separation, collisions = fleet_graph.flown_contacts(t, [a, b], ['a', 'b'], [0.05, 0.05])
    assert separation[1] == 0.0 and len(collisions) == 1
    assert collisions[0][1:3] == ('a', 'b') and 0.0 < collisions[0][0] < 0.01


def test_fly_takes_a_fleet_and_refuses_what_only_one_vehicle_has(tmp_path, ros_env):
    fleet = str(two_abreast(tmp_path))
    done = subprocess.run([QUADFLIGHT, 'fly', fleet, '--controller', 'pid'], env=ros_env, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 2 and '--controller pid refused' in done.stderr and 'fleet mission' in done.stderr
    out = tmp_path / 'run'
    done = subprocess.run([QUADFLIGHT, 'fly', fleet, '--out', str(out)], env=ros_env, capture_output=True,
                          text=True, timeout=TIMEOUT_S)
    assert done.returncode == 0, done.stdout + done.stderr
    assert 'through the ROS graph' in done.stdout
    assert sorted(p.name for p in (out / 'vehicles').iterdir()) == ['cf1', 'cf2']
    assert (out / 'vehicles' / 'cf2' / 'figures' / 'fig1_position_velocity.png').is_file()
    # the verdict is printed before the vehicles' figures are drawn (they take most of the reports' time)
    assert done.stdout.index('flown minimum separation') < done.stdout.index("wrote each vehicle's report")
