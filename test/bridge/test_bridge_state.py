"""The bridge's own state over real UDP with the emulated autopilots, seen on the wire by a tap: a log site that
keeps one severity, land stays land whatever the stale check finds, PX4's one-second pre-stream, `vehicle/engaged`
only once the vehicle's heartbeat shows the mode, and a Ctrl-C while the vehicle flies our setpoints lands it."""

import signal
import subprocess
import sys
import time

import pytest
from bridge_graph import SetpointPublisher, Tap, bridge_in_this_process, tapped_graph
from std_msgs.msg import Bool
from std_srvs.srv import SetBool, Trigger

from quad_bringup.emulated.vehicle_graph import ROOT, WAIT_S, Observer, Processes, free_udp_port, running_graph
from quad_common import contract
from quad_common.ros.testing import isolated_domain

HOVER = 0.5
DO_SET_MODE = 176
PX4_OFFBOARD, PX4_LAND, PX4_LOITER = 6 << 16, 4 << 16 | 6 << 24, 4 << 16 | 3 << 24
COPTER_GUIDED_NOGPS, COPTER_LAND = 20, 9
OFFBOARD = {'px4': ('OFFBOARD', PX4_OFFBOARD), 'ardupilot': ('GUIDED_NOGPS', COPTER_GUIDED_NOGPS)}
LAND = {'px4': ('AUTO.LAND', PX4_LAND), 'ardupilot': ('LAND', COPTER_LAND)}
VEHICLE_ARGS = {'px4': ('--offboard-loss-s', '3.0'), 'ardupilot': ('--param', 'GUID_OPTIONS=8')}


def _mode_commands(tap, since_s=0.0):
    """(time, COMMAND_LONG) of every DO_SET_MODE the bridge sent since since_s."""
    return [(t, m) for t, m in tap.commands() if m.command == DO_SET_MODE and t >= since_s]


def _is(m, flavour, custom_mode):
    """A DO_SET_MODE m asks for custom_mode (PX4: main << 16 | sub << 24 from param2 / param3)."""
    if flavour == 'px4':
        return (int(m.param2) << 16 | int(m.param3) << 24) == custom_mode
    return int(m.param2) == custom_mode


class EngagedLog:
    """Every vehicle/engaged message (monotonic arrival time, value) the observer receives."""

    def __init__(self, observer):
        self.values = []
        observer.node.create_subscription(Bool, contract.ENGAGED, self._on, contract.qos(contract.ENGAGED))

    def _on(self, msg):
        self.values.append((time.monotonic(), msg.data))

    def first_true(self):
        return next((t for t, v in self.values if v), None)


@pytest.fixture
def graph(tmp_path):
    with tapped_graph(tmp_path) as (procs, observer, start_tapped):
        def start(flavour, **bridge_params):
            return start_tapped(flavour, (0.0, 0.0, 1.0), (*VEHICLE_ARGS[flavour], '--hover-throttle', str(HOVER)),
                                hover_throttle=HOVER, **bridge_params)
        yield procs, observer, start


def _offboard(observer, tap, flavour):
    observer.wait_for(lambda: int(observer.setpoints()[1].get('received', 0)) > 10, 'the bridge to hear setpoints')
    result = observer.call('offboard', SetBool.Request(data=True))
    assert result.success, result.message
    mode = OFFBOARD[flavour][0]
    observer.wait_for(lambda: observer.link()[1].get('mode') == mode, f'mode {mode}')


def test_the_quiet_stream_report_logs_at_either_severity_from_one_bridge(tmp_path):
    """The report of a quiet wire is an info when nothing is commanded and an error when the setpoints went stale:
    one call site at two severities made rclpy raise on the second and skip the diagnostics after it."""
    with running_graph(tmp_path) as (procs, observer):
        with bridge_in_this_process(observer, observer.node.get_namespace(),
                                    f'udpin:127.0.0.1:{free_udp_port()}') as bridge:
            bridge.supervisor.on_stream_quiet(0.6, 0.1)    # the wire went quiet, setpoints fresh, nothing obeys: info
            bridge.supervisor.on_stream_quiet(0.6, 0.6)    # the setpoints stopped: error
            bridge.supervisor.on_stream_quiet(0.6, 0.1)
            assert bridge.supervisor.stale_events == 1


@pytest.mark.parametrize('stale_action', ['hold', 'land'])
def test_after_our_land_nothing_but_land_while_the_heartbeat_still_shows_offboard(graph, stale_action):
    """land is accepted; the vehicle's next heartbeat (1 Hz) comes after the stale check: that check must follow
    the mode we commanded and the vehicle acknowledged (AUTO.LAND obeys no setpoint), not the last heartbeat
    (OFFBOARD): no AUTO.LOITER (stale_action hold), no second AUTO.LAND (stale_action land)."""
    procs, observer, start = graph
    tap = start('px4', stale_action=stale_action)
    publisher = SetpointPublisher(observer)
    try:
        _offboard(observer, tap, 'px4')
        tap.drop_kinds.add('HEARTBEAT')    # the heartbeat showing AUTO.LAND arrives after the stale check
        called_s = time.monotonic()
        result = observer.call('land', Trigger.Request())
        assert result.success, result.message
        observer.wait_for(lambda: 'setpoint stream stopped' in procs.log('bridge'), 'the quiet-stream check')
        tap.drop_kinds.clear()
        observer.wait_for(lambda: observer.link()[1].get('mode') == 'AUTO.LAND', 'the heartbeat showing AUTO.LAND')
    finally:
        publisher.stop()
    commands = _mode_commands(tap, called_s)
    assert len(commands) == 1 and _is(commands[0][1], 'px4', PX4_LAND), \
        f'after land the bridge sent {[(int(m.param2), int(m.param3)) for _, m in commands]}'
    assert 'nothing commanded (vehicle in AUTO.LAND' in procs.log('bridge')


@pytest.mark.parametrize('flavour', ['px4', 'ardupilot'])
def test_engaged_only_once_the_heartbeat_shows_the_mode_after_a_one_second_prestream(graph, flavour):
    """PX4: setpoints stream about 1 s before DO_SET_MODE OFFBOARD. Both: `vehicle/engaged` stays false after the
    ACK until a heartbeat shows the mode (held back here for a while), then goes true."""
    procs, observer, start = graph
    tap = start(flavour)
    engaged = EngagedLog(observer)
    publisher = SetpointPublisher(observer)
    name, custom_mode = OFFBOARD[flavour]
    try:
        observer.wait_for(lambda: int(observer.setpoints()[1].get('received', 0)) > 10, 'the bridge to hear setpoints')
        tap.drop_kinds.add('HEARTBEAT')
        called_s = time.monotonic()
        result = observer.call('offboard', SetBool.Request(data=True))
        answered_s = time.monotonic()
        assert result.success, result.message
        observer.wait_for(lambda: observer.setpoints()[1].get('handover') == 'active', 'the hand-over ACTIVE')
        observer.wait_for(lambda: time.monotonic() > answered_s + 1.0, '1 s after the ACK')  # heartbeats held back
        assert engaged.first_true() is None, 'engaged before any heartbeat showed ' + name
        tap.drop_kinds.clear()
        observer.wait_for(lambda: engaged.first_true() is not None or observer.setpoints()[1].get('handover') ==
                          'idle', 'vehicle/engaged true or the hand-over ended')
        assert engaged.first_true() is not None, f'never engaged: {observer.setpoints()}'
    finally:
        publisher.stop()
    shown = [t for t, mode in tap.heartbeats_since(called_s) if mode == custom_mode]
    assert shown and engaged.first_true() >= shown[0], 'engaged before the heartbeat showed ' + name
    print(f'{flavour}: engaged {engaged.first_true() - shown[0]:.3f} s after the first heartbeat showing {name}')
    switch = [t for t, m in _mode_commands(tap, called_s) if _is(m, flavour, custom_mode)]
    assert switch, f'no DO_SET_MODE {name} on the wire'
    if flavour == 'px4':
        streamed = [t for t, _ in tap.setpoints(called_s) if t < switch[0]]
        assert streamed and switch[0] - streamed[0] >= 0.9, \
            f'pre-stream {switch[0] - streamed[0] if streamed else 0:.3f} s before OFFBOARD'
        # a stream at the bridge's 50 Hz, at least half of it (PX4 asks for more than 2 Hz): at make test's load
        # (~9) the tap counted 37 and 38 in that second
        assert len(streamed) >= 25, f'{len(streamed)} setpoints before OFFBOARD at 50 Hz'
        print(f'pre-stream {switch[0] - streamed[0]:.3f} s, {len(streamed)} setpoints before DO_SET_MODE OFFBOARD')
    else:
        assert not [1 for t, _ in tap.setpoints(called_s) if t < switch[0]], 'ArduPilot streamed before its switch'


@pytest.mark.parametrize('flavour', ['px4', 'ardupilot'])
def test_ctrl_c_while_the_vehicle_flies_our_setpoints_lands_it_then_exits_0(tmp_path, flavour):
    """The bridge started as launch_ros starts it (`python -m`, --ros-args, -r __node:=, the shipped params file),
    the vehicle handed over; SIGINT: DO_SET_MODE land on the wire, the vehicle lands, the bridge exits 0."""
    with isolated_domain() as (domain, env):
        procs = Processes(env, tmp_path, '/')
        observer = Observer(domain, '/')
        bridge_port = free_udp_port()
        tap = Tap(bridge_port)
        publisher = None
        try:
            procs.vehicle(flavour, f'udpout:127.0.0.1:{tap.port}',
                          extra=(*VEHICLE_ARGS[flavour], '--hover-throttle', str(HOVER)))
            log = open(tmp_path / 'bridge.log', 'w')
            bridge = subprocess.Popen(
                [sys.executable, '-m', 'quad_bridge.mavlink_bridge_node', '--ros-args', '-r', '__node:=mavlink_bridge',
                 '--params-file', str(ROOT / 'config' / f'bridge_{flavour}.yaml'),
                 '-p', f'fcu_url:=udpin:127.0.0.1:{bridge_port}'],
                env=procs.env, stdout=log, stderr=subprocess.STDOUT, cwd=str(ROOT))
            procs.procs['bridge'] = bridge
            observer.wait_for(lambda: observer.link()[1].get('armed') == 'True' or bridge.poll() is not None,
                              'the bridge to see the armed vehicle')
            assert bridge.poll() is None, f'the bridge exited with {bridge.returncode}: {procs.log("bridge")[-2000:]}'
            publisher = SetpointPublisher(observer)
            _offboard(observer, tap, flavour)
            stopped_s = time.monotonic()
            bridge.send_signal(signal.SIGINT)
            rc = bridge.wait(timeout=WAIT_S)
            print(f'{flavour}: the bridge exited {time.monotonic() - stopped_s:.2f} s after SIGINT')
            procs.procs.pop('bridge')
            land_name, land_mode = LAND[flavour]
            deadline = time.monotonic() + WAIT_S
            while not any(mode == land_mode for _, mode in tap.heartbeats_since(stopped_s)):
                assert time.monotonic() < deadline, f'the vehicle never reported {land_name}'
                time.sleep(0.05)
        finally:
            if publisher:
                publisher.stop()
            tap.close()
            procs.stop_all()
            observer.close()
        text = procs.log('bridge')
        assert rc == 0, f'exit status {rc}:\n{text[-2000:]}'
        lands = [t for t, m in _mode_commands(tap, stopped_s) if _is(m, flavour, land_mode)]
        assert lands, f'no DO_SET_MODE {land_name} after SIGINT:\n{text[-2000:]}'
        assert f'commanding {land_name}' in text and f'{land_name}: MAV_RESULT_ACCEPTED' in text, text[-2000:]
        assert 'Traceback' not in text
