"""External pose: frame conversion, its time (the TIMESYNC answers' clock), rate limit, faults (timeout, jump,
late)."""

import dataclasses
import math

import numpy as np
import pytest

from quad_bridge import frames
from quad_bridge.external_pose import ExternalPoseConfig, ExternalPoseFilter, ends_handover
from quad_common import rotations
from quad_common.mocap_frames import to_enu

MS = 1_000_000


def _filter(**kw):
    return ExternalPoseFilter(ExternalPoseConfig(**kw))


def test_enu_is_converted_to_ned_frd_by_frames():
    f = _filter()
    q = rotations.from_yaw(0.3)
    t = 7_000 * MS
    out = f.offer([1.0, 2.0, 3.0], q, [0.1, 0.2, 0.3], t, t + 10 * MS)   # velocity in body FLU (the twist)
    np.testing.assert_allclose(out.position_ned, [2.0, 1.0, -3.0])
    np.testing.assert_allclose(out.velocity_frd, [0.1, -0.2, -0.3])
    v_enu = rotations.to_matrix(q) @ [0.1, 0.2, 0.3]
    np.testing.assert_allclose(out.velocity_ned, [v_enu[1], v_enu[0], -v_enu[2]])
    np.testing.assert_allclose(out.quaternion_ned_frd, frames.quaternion_enu_to_ned(q))
    yaw_ned = rotations.to_euler(out.quaternion_ned_frd)[2]
    assert math.isclose(yaw_ned, math.pi / 2 - 0.3, abs_tol=1e-9)


def test_y_up_is_a_rotation_about_x():
    # Y-up: up is +y; forward x stays x; the world z axis (x cross y) is ENU -y.
    p, q, v = to_enu('y_up', [1.0, 2.0, 3.0], [0, 0, 0, 1], [0.0, 1.0, 0.0])
    np.testing.assert_allclose(p, [1.0, -3.0, 2.0])
    np.testing.assert_allclose(v, [0.0, 0.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(rotations.to_matrix(q), np.eye(3), atol=1e-12)
    # a yaw in Y-up is a rotation about its up axis (y): the same yaw about ENU z.
    yaw = 0.4
    q_yup = np.array([0.0, math.sin(yaw / 2), 0.0, math.cos(yaw / 2)])
    _, q, _ = to_enu('y_up', [0, 0, 0], q_yup)
    assert math.isclose(rotations.to_euler(q)[2], yaw, abs_tol=1e-9)


def test_bad_frame_names_it():
    with pytest.raises(ValueError, match='external_pose_frame.*z_up'):
        ExternalPoseConfig(frame='z_up')


def test_the_stamp_goes_out_in_the_clock_the_bridge_answers_timesync_with():
    """Local ROS time in us, not the autopilot's boot time: PX4 maps it through its TIMESYNC offset to our answers."""
    t = 1_765_000_000_123_456_789   # a wall-clock stamp (ns)
    out = _filter().offer([0, 0, 0], [0, 0, 0, 1], None, t, t + 10 * MS)
    assert out.time_us == t // 1000


def test_rate_limited_to_max_rate():
    f = _filter(max_rate_hz=30.0)
    t0 = 7_000 * MS
    sent = [f.offer([0, 0, 0], [0, 0, 0, 1], None, t0 + k * 5 * MS, t0 + k * 5 * MS + MS) for k in range(200)]
    n = sum(out is not None for out in sent)   # 200 samples at 200 Hz over 1 s
    assert 28 <= n <= 31, n
    assert f.dropped_rate == 200 - n
    assert 28 <= f.rate_hz(t0 + 1000 * MS) <= 31
    f = _filter(max_rate_hz=30.0)   # 12 ms apart: every third (36 ms) would be 27.8 Hz; the due time keeps 30
    sent = [f.offer([0, 0, 0], [0, 0, 0, 1], None, t0 + k * 12 * MS, t0 + k * 12 * MS + MS) for k in range(250)]
    assert 89 <= sum(out is not None for out in sent) <= 91   # 3 s


def test_jump_is_a_fault_and_not_forwarded():
    f = _filter(max_speed_m_s=5.0, jump_margin_m=0.1)
    t = 7_000 * MS
    assert f.offer([0, 0, 1], [0, 0, 0, 1], None, t, t + MS) is not None
    t += 40 * MS   # 40 ms: 0.2 m + 0.1 m allowed
    assert f.offer([0.25, 0, 1], [0, 0, 0, 1], None, t, t + MS) is not None
    t += 40 * MS
    assert f.offer([1.5, 0, 1], [0, 0, 0, 1], None, t, t + MS) is None
    assert f.fault.startswith('jump: 1.25 m in 40 ms')


def test_late_sample_is_a_fault():
    f = _filter(max_age_s=0.2)
    t = 7_000 * MS
    assert f.offer([0, 0, 0], [0, 0, 0, 1], None, t, t + 250 * MS) is None
    assert f.fault.startswith('late: stamp 250 ms old') and f.dropped_late == 1
    assert f.offer([0, 0, 0], [0, 0, 0, 1], None, t + 300 * MS, t + 310 * MS) is not None
    assert f.fault is None


def test_a_late_sample_is_dropped_but_does_not_end_a_hand_over_as_a_jump_or_a_timeout_does():
    assert not ends_handover('late: stamp 358 ms old > 200 ms')
    assert ends_handover('jump: 5.00 m in 10 ms > 0.20 m') and ends_handover('timeout: no sample for 0.60 s')
    assert ends_handover('bad sample: zero quaternion') and not ends_handover(None)


def test_a_late_burst_shorter_than_the_timeout_leaves_no_fault_once_timely_samples_come_back():
    f = _filter(max_age_s=0.2, timeout_s=0.5, max_rate_hz=100.0)
    t = 7_000 * MS
    assert f.offer([0, 0, 0], [0, 0, 0, 1], None, t, t + MS) is not None
    for k in range(1, 30):   # 0.3 s of samples each 350 ms old: a publisher that stalled
        assert f.offer([0, 0, 0], [0, 0, 0, 1], None, t + k * 10 * MS - 350 * MS, t + k * 10 * MS) is None
    assert f.check_timeout(t + 300 * MS).startswith('late') and f.dropped_late == 29
    assert f.offer([0, 0, 0], [0, 0, 0, 1], None, t + 300 * MS, t + 301 * MS) is not None
    assert f.fault is None and f.check_timeout(t + 310 * MS) is None


def test_only_late_samples_for_the_timeout_is_a_timeout_though_samples_arrive():
    f = _filter(max_age_s=0.2, timeout_s=0.5)
    t = 7_000 * MS
    f.offer([0, 0, 0], [0, 0, 0, 1], None, t, t + MS)
    for k in range(1, 61):
        f.offer([0, 0, 0], [0, 0, 0, 1], None, t + k * 10 * MS - 300 * MS, t + k * 10 * MS)
    assert f.check_timeout(t + 400 * MS).startswith('late')
    fault = f.check_timeout(t + 600 * MS)
    assert fault.startswith('timeout: no timely sample for 0.60 s (the newest 300 ms old)'), fault
    assert ends_handover(fault)
    g = _filter(max_age_s=0.2, timeout_s=0.5)
    g.offer([0, 0, 0], [0, 0, 0, 1], None, t, t + 300 * MS)
    assert g.check_timeout(t + 300 * MS).startswith('timeout: no timely sample ever')


def test_timeout_when_the_stream_stops():
    f = _filter(timeout_s=0.5)
    t = 7_000 * MS
    assert f.check_timeout(t).startswith('timeout: never received')
    f.offer([0, 0, 0], [0, 0, 0, 1], None, t, t + MS)
    assert f.check_timeout(t + 400 * MS) is None
    assert f.check_timeout(t + 600 * MS).startswith('timeout: no sample for 0.60 s')


def _wire(backend, pose):
    """The backend's messages as MAVLink 2 bytes, parsed back by pymavlink (what the autopilot receives)."""
    from quad_bridge.mavlink_client import mavlink
    sender, receiver = mavlink.MAVLink(None, srcSystem=255, srcComponent=191), mavlink.MAVLink(None)
    out = []
    for name, args in backend.external_pose_messages(pose):
        msg = getattr(sender, name + '_encode')(*args)
        out += receiver.parse_buffer(msg.pack(sender)) or []
    return out


def _pose():
    f = _filter()
    q = rotations.from_euler(0.1, -0.2, 0.3)   # ENU/FLU
    t = 7_000 * MS
    return f.offer([1.0, 2.0, 3.0], q, [1.0, 0.5, -0.2], t, t + MS), q


def test_px4_gets_odometry_local_frd_body_frd_from_vision():
    from quad_bridge.px4 import Px4
    pose, q_enu = _pose()
    (msg,) = _wire(Px4(), pose)
    assert msg.get_type() == 'ODOMETRY'
    assert (msg.frame_id, msg.child_frame_id, msg.estimator_type) == (20, 12, 2)   # LOCAL_FRD, BODY_FRD, VISION
    assert msg.time_usec == pose.time_us
    np.testing.assert_allclose([msg.x, msg.y, msg.z], [2.0, 1.0, -3.0], atol=1e-6)
    q_wxyz = np.array(msg.q)   # body FRD -> NED, (w, x, y, z)
    np.testing.assert_allclose(frames.from_mavlink_quaternion(q_wxyz), frames.quaternion_enu_to_ned(q_enu),
                               atol=1e-6)
    np.testing.assert_allclose([msg.vx, msg.vy, msg.vz], [1.0, -0.5, 0.2], atol=1e-6)   # body FRD
    assert math.isnan(msg.pose_covariance[0]) and math.isnan(msg.rollspeed)


def test_ardupilot_gets_vision_position_and_speed_estimate():
    from quad_bridge.ardupilot import ArduPilot
    pose, q_enu = _pose()
    position, speed = _wire(ArduPilot(), pose)
    assert (position.get_type(), speed.get_type()) == ('VISION_POSITION_ESTIMATE', 'VISION_SPEED_ESTIMATE')
    assert position.usec == speed.usec == pose.time_us
    np.testing.assert_allclose([position.x, position.y, position.z], [2.0, 1.0, -3.0], atol=1e-6)
    q_ned = rotations.from_euler(position.roll, position.pitch, position.yaw)
    np.testing.assert_allclose(rotations.to_matrix(q_ned), rotations.to_matrix(frames.quaternion_enu_to_ned(q_enu)),
                               atol=1e-6)
    v_enu = rotations.to_matrix(q_enu) @ [1.0, 0.5, -0.2]
    np.testing.assert_allclose([speed.x, speed.y, speed.z], [v_enu[1], v_enu[0], -v_enu[2]], atol=1e-6)
    assert all(c == 0.0 for c in position.covariance)   # ArduPilot sums three of them: a NaN would poison it
    without_velocity = dataclasses.replace(pose, velocity_frd=None)
    assert [m.get_type() for m in _wire(ArduPilot(), without_velocity)] == ['VISION_POSITION_ESTIMATE']


PX4_OK = {'MPC_THR_HOVER': 0.5, 'COM_OF_LOSS_T': 1.0, 'EKF2_EV_CTRL': 15, 'EKF2_HGT_REF': 3, 'EKF2_GPS_CTRL': 0,
          'EKF2_EV_DELAY': 10.0}
AP_OK = {'GUID_OPTIONS': 8, 'ATC_ANGLE_BOOST': 1, 'MOT_THST_HOVER': 0.5, 'VISO_TYPE': 1, 'EK3_SRC1_POSXY': 6,
         'EK3_SRC1_VELXY': 6, 'EK3_SRC1_POSZ': 6, 'EK3_SRC1_YAW': 6}


@pytest.mark.parametrize('policy', ['check', 'adopt'])
def test_px4_external_vision_parameters_are_checked_with_an_external_pose(policy):
    from quad_bridge.backend import BridgeConfig
    from quad_bridge.px4 import Px4
    config = BridgeConfig(external_pose_enabled=True)
    assert set(Px4().param_names(config)) >= {'EKF2_EV_CTRL', 'EKF2_HGT_REF', 'EKF2_GPS_CTRL', 'EKF2_EV_DELAY'}
    assert not set(Px4().param_names(BridgeConfig())) & {'EKF2_EV_CTRL'}
    ok = Px4().check_params(PX4_OK, config, policy)
    assert ok.problems == () and any('EKF2_EV_DELAY = 10 ms' in n for n in ok.notes)
    bad = Px4().check_params({**PX4_OK, 'EKF2_EV_CTRL': 0, 'EKF2_HGT_REF': 0, 'EKF2_GPS_CTRL': 7}, config, policy)
    assert [p.split(' =')[0] for p in bad.problems] == ['EKF2_EV_CTRL', 'EKF2_HGT_REF']
    assert 'EKF2_EV_CTRL = 3' in bad.problems[0]
    assert any(n.startswith('EKF2_GPS_CTRL = 7') for n in bad.notes)
    assert Px4().check_params({**PX4_OK, 'EKF2_EV_CTRL': 0}, BridgeConfig(), policy).problems == ()
    missing = dict(PX4_OK)
    del missing['EKF2_HGT_REF']
    assert 'EKF2_HGT_REF' in Px4().check_params(missing, config, policy).problems[0]


def test_ardupilot_external_vision_parameters_are_checked_with_an_external_pose():
    from quad_bridge.ardupilot import ArduPilot
    from quad_bridge.backend import BridgeConfig
    config = BridgeConfig(external_pose_enabled=True)
    assert ArduPilot().check_params(AP_OK, config, 'check').problems == ()
    bad = ArduPilot().check_params({**AP_OK, 'VISO_TYPE': 0, 'EK3_SRC1_POSXY': 3, 'EK3_SRC1_VELXY': 3,
                                    'EK3_SRC1_POSZ': 1, 'EK3_SRC1_YAW': 0}, config, 'check')
    assert [p.split(' =')[0] for p in bad.problems] == ['VISO_TYPE', 'EK3_SRC1_POSXY', 'EK3_SRC1_VELXY',
                                                        'EK3_SRC1_YAW']
    assert any(n.startswith('EK3_SRC1_POSZ = 1: from the barometer') for n in bad.notes)
