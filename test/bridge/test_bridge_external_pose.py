"""An external pose (motion capture) through the bridge over real UDP to the emulated autopilots, seen on the wire by
a tap: forwarded in the autopilot's message at the configured rate, converted to NED; a jump, a late sample and a
stopped stream are faults in the diagnostics and refuse `offboard`; a jump, a stopped stream and only late samples
for the timeout end a hand-over with stale_action, a short late burst is dropped and the hand-over goes on.
The bridge's vehicle-parameter check reads the emulator's external vision parameters: set as the
autopilots' docs say, offboard runs; left at their defaults, it is refused naming the parameter. With them set the
vehicle's estimate (its odometry, through the bridge) is the pose it was sent, not where it is: a rigid body 1 m
off, or a Y-up frame declared for an ENU pose, moves the reported position by as much."""

import threading
import time

import pytest
from bridge_graph import SetpointPublisher, tapped_graph
from geometry_msgs.msg import PoseStamped
from std_srvs.srv import SetBool

from quad_bringup.emulated.vehicle_graph import free_udp_port, running_graph
from quad_common import contract

HOVER = 0.5
VEHICLE_ARGS = {'px4': ('--offboard-loss-s', '3.0'), 'ardupilot': ('--param', 'GUID_OPTIONS=8')}
WIRE = {'px4': 'ODOMETRY', 'ardupilot': 'VISION_POSITION_ESTIMATE'}
STATUS = 'mavlink_bridge: external pose'
DO_SET_MODE = 176


class PosePublisher:
    """external/pose at rate_hz from a thread; position and stamp age can be changed while it runs."""

    def __init__(self, observer, rate_hz=100.0, position=(1.0, 2.0, 0.5)):
        self.node, self.period_s = observer.node, 1.0 / rate_hz
        self.pub = self.node.create_publisher(PoseStamped, contract.EXTERNAL_POSE, contract.qos(contract.EXTERNAL_POSE))
        self.position, self.age_s = position, 0.0
        self.late_left, self.late_age_s = 0, 0.0   # the next late_left samples late_age_s old (a stalled publisher)
        self.running = threading.Event()
        self.running.set()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        while self.running.is_set():
            msg = PoseStamped()
            age_s = self.age_s
            if self.late_left > 0:
                self.late_left, age_s = self.late_left - 1, self.late_age_s
            t_ns = time.time_ns() - int(age_s * 1e9)
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(t_ns, 1_000_000_000)
            msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = self.position
            msg.pose.orientation.w = 1.0
            self.pub.publish(msg)
            time.sleep(self.period_s)   # pacing the publisher, not synchronisation

    def late_burst(self, count, age_s):
        self.late_age_s, self.late_left = age_s, count

    def stop(self):
        self.running.clear()
        self.thread.join(timeout=2)


@pytest.fixture
def graph(tmp_path):
    with tapped_graph(tmp_path) as (procs, observer, start_tapped):
        def start(flavour, vehicle_args=(), **bridge_params):
            return start_tapped(flavour, (0.0, 0.0, 1.0),
                                (*VEHICLE_ARGS[flavour], *vehicle_args, '--hover-throttle', str(HOVER)),
                                hover_throttle=HOVER, external_pose_enabled=True, **bridge_params)
        yield procs, observer, start


# the vehicle set for external vision as the autopilots' docs say (no GPS, height and position from vision)
EV_PARAMS = {'px4': ('EKF2_EV_CTRL=3', 'EKF2_HGT_REF=3', 'EKF2_GPS_CTRL=0', 'EKF2_EV_DELAY=20'),
             'ardupilot': ('VISO_TYPE=1', 'EK3_SRC1_POSXY=6', 'EK3_SRC1_VELXY=6', 'EK3_SRC1_POSZ=6',
                           'EK3_SRC1_YAW=6')}
UNSET = {'px4': 'EKF2_HGT_REF = 1', 'ardupilot': 'VISO_TYPE = 0'}


def _fault(observer):
    return observer.status(STATUS)[1].get('fault', '')


def _handed_over(observer):
    result = observer.call('offboard', SetBool.Request(data=True))
    assert result.success, result.message
    observer.wait_for(lambda: observer.setpoints()[1].get('handover') == 'active', 'the hand-over active')


@pytest.mark.parametrize('flavour', ['px4', 'ardupilot'])
def test_external_pose_is_forwarded_and_its_faults_end_the_hand_over(graph, flavour):
    """A jump ends the hand-over at once; late samples are dropped and end it only when no timely one comes for
    external_pose_timeout_s (2 s here: a busy machine must not turn the 0.1 s late burst into a timeout)."""
    procs, observer, start = graph
    tap = start(flavour, vehicle_params='ignore', external_pose_rate_hz=30.0, external_pose_timeout_s=2.0,
                setpoint_timeout_s=1.0)   # the test's own setpoints: a busy 2-core machine's stalls, as elsewhere
    kind = WIRE[flavour]
    assert _fault(observer).startswith('timeout: never received') or not observer.status(STATUS)[0]
    poses = PosePublisher(observer)
    observer.wait_for(lambda: len(tap.sent_of(kind)) > 60, f'{kind} on the wire')
    sent = tap.sent_of(kind)
    t, m = sent[-1]
    assert (m.x, m.y, m.z) == pytest.approx((2.0, 1.0, -0.5), abs=1e-5)   # ENU (1, 2, 0.5) in NED
    if flavour == 'px4':
        assert (m.frame_id, m.child_frame_id, m.estimator_type) == (20, 12, 2)
        observer.wait_for(lambda: int(observer.link()[1].get('timesync_requests_answered', 0)) > 0,
                          "PX4's TIMESYNC requests answered")   # it maps the stamps after 500 of them
    window = [s for s, _ in sent if s > sent[-1][0] - 1.0]
    assert 25 <= len(window) <= 32, len(window)   # 100 Hz published, 30 Hz forwarded
    observer.wait_for(lambda: observer.status(STATUS)[0] == 'forwarding', 'the external pose status forwarding')

    setpoints = SetpointPublisher(observer, force_mps2=9.81)
    try:
        observer.wait_for(lambda: int(observer.setpoints()[1].get('received', 0)) > 10, 'setpoints heard')
        _handed_over(observer)
        poses.late_burst(10, 0.35)                            # 0.1 s of poses 350 ms old, then timely again
        observer.wait_for(lambda: int(observer.status(STATUS)[1].get('dropped_late', 0)) >= 10 and
                          observer.status(STATUS)[0] == 'forwarding', 'the late samples dropped, then forwarding')
        assert observer.setpoints()[1].get('handover') == 'active'
        assert observer.status(STATUS)[1].get('handovers_ended') == '0'
        since = time.monotonic()
        poses.position = (6.0, 2.0, 0.5)                     # 5 m in one sample: a swapped rigid body
        observer.wait_for(lambda: _fault(observer).startswith('jump'), 'the jump fault')
        observer.wait_for(lambda: observer.setpoints()[1].get('handover') != 'active', 'the hand-over ended')
        assert 'external pose: jump' in observer.setpoints()[0]
        observer.wait_for(lambda: any(m.command == DO_SET_MODE for _, m in tap.sent_of('COMMAND_LONG', since)),
                          'stale_action commanded')
        assert not [m for _, m in tap.sent_of(kind, since) if abs(m.x - 2.0) > 1.0]   # the jump never went out
        result = observer.call('offboard', SetBool.Request(data=True))
        assert not result.success and 'external pose jump' in result.message, result.message
        poses.position = (1.0, 2.0, 0.5)                     # back in place: forwarded again
        observer.wait_for(lambda: observer.status(STATUS)[0] == 'forwarding', 'forwarding again')
        _handed_over(observer)
        poses.age_s = 0.5                                    # every pose 500 ms old from now on
        observer.wait_for(lambda: _fault(observer).startswith('late'), 'the late fault')
        observer.wait_for(lambda: observer.setpoints()[1].get('handover') != 'active', 'the hand-over ended')
        assert 'external pose: timeout: no timely sample for' in observer.setpoints()[0], observer.setpoints()[0]
        assert observer.status(STATUS)[1].get('handovers_ended') == '2'
    finally:
        setpoints.stop()
    poses.stop()
    observer.wait_for(lambda: _fault(observer).startswith('timeout: no sample'), 'the timeout fault')


@pytest.mark.parametrize('flavour', ['px4', 'ardupilot'])
@pytest.mark.parametrize('ev_params_set', [True, False])
def test_vehicle_param_check_reads_the_emulators_external_vision_parameters(graph, flavour, ev_params_set):
    procs, observer, start = graph
    args = [a for value in EV_PARAMS[flavour] for a in ('--param', value)] if ev_params_set else []
    start(flavour, vehicle_args=args, vehicle_params='check')
    poses = PosePublisher(observer, position=(0.0, 0.0, 1.0))   # where the vehicle is: its estimate follows it
    setpoints = SetpointPublisher(observer, force_mps2=9.81)
    try:
        observer.wait_for(lambda: observer.status(STATUS)[0] == 'forwarding', 'the external pose status forwarding')
        observer.wait_for(lambda: int(observer.setpoints()[1].get('received', 0)) > 10, 'setpoints heard')
        result = observer.call('offboard', SetBool.Request(data=True))
        if ev_params_set:
            assert result.success, result.message
        else:
            assert not result.success and UNSET[flavour] in result.message, result.message
    finally:
        setpoints.stop()
        poses.stop()


def test_px4_without_gps_or_pose_refuses_to_arm_and_the_bridge_says_why_then_arms_once_the_pose_streams(tmp_path):
    """PX4 on the ground with its GPS off and external vision on has no position until a pose arrives: the bridge's
    `arm` is refused with the autopilot's own reason (its STATUSTEXTs, joined from their chunks), not a bare result
    code; with the pose streaming it arms."""
    with running_graph(tmp_path) as (procs, observer):
        port = free_udp_port()
        ev = [a for value in EV_PARAMS['px4'] for a in ('--param', value)]
        procs.vehicle('px4', f'udpout:127.0.0.1:{port}', position=(0.0, 0.0, 0.0),
                      extra=(*VEHICLE_ARGS['px4'], *ev, '--hover-throttle', str(HOVER)))
        procs.bridge(f'udpin:127.0.0.1:{port}', hover_throttle=HOVER, external_pose_enabled=True,
                     vehicle_params='ignore')
        observer.wait_for(lambda: observer.link()[1].get('autopilot') in ('px4', 'PX4'),
                          f'the link up with the PX4 vehicle ({observer.link()})')
        _arm_refused_then_accepted(observer)


def _arm_refused_then_accepted(observer):
    result = observer.call('arm', SetBool.Request(data=True))
    assert not result.success, result.message
    assert 'Preflight Fail: No valid local position estimate' in result.message, result.message
    assert 'Arming denied: Resolve system health failures first' in result.message, result.message   # 2 chunks
    poses = PosePublisher(observer)
    try:
        observer.wait_for(lambda: observer.status(STATUS)[0] == 'forwarding', 'the external pose status forwarding')
        observer.wait_for(lambda: observer.call('arm', SetBool.Request(data=True)).success, 'arming accepted')
    finally:
        poses.stop()


# (autopilot, external_pose_frame, the published pose (ENU, m) of a vehicle standing at TRUTH, the odometry expected)
TRUTH = (1.0, 2.0, 0.0)
FUSED_CASES = [('px4', 'enu', (2.0, 2.0, 0.0), (2.0, 2.0, 0.0)),      # the rigid body's origin 1 m off in x
               ('ardupilot', 'y_up', TRUTH, (1.0, 0.0, 2.0))]          # Y-up: (x, y, z) -> (x, -z, y) ENU


def _near(position, expected, tolerance_m):
    return position is not None and max(abs(a - b) for a, b in zip(position, expected)) < tolerance_m


@pytest.mark.parametrize('flavour,frame,pose,expected', FUSED_CASES, ids=[c[1] for c in FUSED_CASES])
def test_the_vehicles_odometry_is_its_estimate_fused_from_the_pose_not_its_truth(tmp_path, flavour, frame, pose,
                                                                                    expected):
    """A vehicle standing (disarmed) at TRUTH with external vision as its position source: before any pose its
    odometry is where it stands; with the pose streaming the odometry the bridge publishes is the pose as the bridge
    converted it and the autopilot fused it from the wire, and stays there."""
    with running_graph(tmp_path) as (procs, observer):
        port = free_udp_port()
        ev = [a for value in EV_PARAMS[flavour] for a in ('--param', value)]
        procs.vehicle(flavour, f'udpout:127.0.0.1:{port}', position=TRUTH,
                      extra=(*VEHICLE_ARGS[flavour], *ev, '--hover-throttle', str(HOVER)))
        procs.bridge(f'udpin:127.0.0.1:{port}', hover_throttle=HOVER, external_pose_enabled=True,
                     external_pose_frame=frame, vehicle_params='ignore')
        observer.wait_for(lambda: _near(observer.position(), TRUTH, 0.02), f'odometry at the truth {TRUTH}')
        poses = PosePublisher(observer, position=pose)
        try:
            observer.wait_for(lambda: _near(observer.position(), expected, 0.02),
                              f'odometry at the fused pose {expected} (now {observer.position()})')
            since = observer.odom[-1][0]
            observer.wait_for(lambda: observer.odom[-1][0] > since + 1.0, 'one more second of odometry')
            held = [p for t, p in list(observer.odom) if t > since]
            assert all(_near(p, expected, 0.03) for p in held), held[:5]
        finally:
            poses.stop()


@pytest.mark.parametrize('flavour', ['px4', 'ardupilot'])
def test_the_autopilot_fuses_the_bridge_stamped_pose_at_its_capture_instant_after_timesync_converged(flavour):
    """The bridge's stamp rule against each autopilot's own handling of time_usec (the emulator's, from their
    source): PX4 booted 1000 s ago asks TIMESYNC 600 times at 10 Hz (2 ms each way) and the bridge answers with its
    answer clock; ArduPilot's jitter correction sees poses arrive 10 ms after capture. A pose captured at wall time
    c and stamped by the bridge is then fused at c in the autopilot's boot clock (less EKF's half step), not 1000 s
    early (which EKF2 refuses as before boot): PX4 with EKF2_EV_DELAY 0 (the stamp is the capture instant),
    ArduPilot with VISO_DELAY_MS the pose's age (its correction keeps only the stamps' jitter)."""
    from quad_bridge.clock import answer_clock_ns
    from quad_bridge.external_pose import ExternalPoseConfig, ExternalPoseFilter
    from quad_vehicle_emu.external_vision import ARDUPILOT_HALF_EKF_STEP_US, PX4_HALF_EKF_DT_US, VisionClock

    wall0_ns = answer_clock_ns()
    boot_offset_ns = wall0_ns - 1000 * 10**9          # boot time = wall time - this
    vision = VisionClock(flavour)
    if flavour == 'px4':
        for k in range(600):
            ask_boot_ns = (wall0_ns - boot_offset_ns) + k * 100_000_000
            answer_wall_ns = ask_boot_ns + boot_offset_ns + 2_000_000
            vision.timesync.update((ask_boot_ns + 4_000_000) // 1000, answer_wall_ns, ask_boot_ns)
        assert vision.timesync.converged
    poses = ExternalPoseFilter(ExternalPoseConfig(max_rate_hz=200.0))
    half_step_us = PX4_HALF_EKF_DT_US if flavour == 'px4' else ARDUPILOT_HALF_EKF_STEP_US
    for k in range(200):   # 100 Hz captures, 10 ms to the autopilot
        capture_ns = wall0_ns + 60 * 10**9 + k * 10_000_000
        pose = poses.offer([0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 1.0], None, capture_ns, capture_ns + 5_000_000)
        arrival_boot_us = (capture_ns + 10_000_000 - boot_offset_ns) // 1000
        fused_us = vision.fusion_us(pose.time_us, arrival_boot_us, 0.0 if flavour == 'px4' else 10.0)
    assert abs(fused_us + half_step_us - (capture_ns - boot_offset_ns) // 1000) < 1_000   # 1 ms
