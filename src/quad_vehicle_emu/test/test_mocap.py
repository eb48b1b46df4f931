"""The emulator's motion-capture stand-in (no rclpy): quad_sim.mocap's frames of the truth, stamped on the wall
clock at the capture instant, in enu or y_up."""

import math

import numpy as np
import pytest

from quad_common import rotations
from quad_common.mocap_frames import from_enu, to_enu
from quad_sim.mocap import MocapConfig
from quad_vehicle_emu.mavlink_vehicle import main
from quad_vehicle_emu.mocap import MocapStandIn

WALL0_NS = 1_700_000_000_000_000_000


def _poses(frame, config, ticks_s, position, quaternion):
    stand_in = MocapStandIn(config, frame, WALL0_NS, loop_rate_hz=100.0)
    return [pose for t in ticks_s for pose in stand_in.offer(t, position, quaternion)]


def test_frames_are_stamped_at_the_capture_instant_on_the_wall_clock_and_delivered_late():
    ticks = np.arange(0, 101) * 0.01                    # the emulator's loop at 100 Hz over 1 s
    stand_in = MocapStandIn(MocapConfig(rate_hz=50.0, latency_s=0.03), 'enu', WALL0_NS, loop_rate_hz=100.0)
    delivered = [(t, pose) for t in ticks for pose in stand_in.offer(t, [1.0, 2.0, 0.5], [0, 0, 0, 1])]
    stamps_s = np.array([(p.stamp_ns - WALL0_NS) * 1e-9 for _, p in delivered])
    np.testing.assert_allclose(np.diff(stamps_s), 0.02, atol=1e-9)          # 50 Hz on the capture instants
    assert stamps_s[0] == 0.0 and len(delivered) == 49                      # 0.98 s captured by 1.0 - 0.03
    for t, pose in delivered:
        assert t - (pose.stamp_ns - WALL0_NS) * 1e-9 == pytest.approx(0.03, abs=1e-9)   # the latency
        np.testing.assert_allclose(pose.position, [1.0, 2.0, 0.5])


def test_y_up_is_what_to_enu_turns_back_into_the_truth():
    yaw = 0.7
    q = np.array([0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)])
    (pose,) = _poses('y_up', MocapConfig(rate_hz=100.0), [0.0], [1.0, 2.0, 3.0], q)
    np.testing.assert_allclose(pose.position, [1.0, 3.0, -2.0])              # up is +y
    p, q_enu, _ = to_enu('y_up', pose.position, pose.quaternion)
    np.testing.assert_allclose(p, [1.0, 2.0, 3.0], atol=1e-12)
    assert abs(rotations.multiply(rotations.conjugate(q_enu), q)[3]) == pytest.approx(1.0, abs=1e-12)
    p, q_back = from_enu('enu', [1.0, 2.0, 3.0], q)
    np.testing.assert_allclose(p, [1.0, 2.0, 3.0])
    np.testing.assert_allclose(q_back, q)


def test_noise_is_quad_sim_mocaps():
    config = MocapConfig(rate_hz=100.0, position_noise_m=0.002)
    poses = _poses('enu', config, np.arange(0, 2001) * 0.01, [0.0, 0.0, 1.0], [0, 0, 0, 1])
    error = np.array([p.position for p in poses]) - [0.0, 0.0, 1.0]
    assert error.std(axis=0) == pytest.approx([0.002] * 3, rel=0.1)


@pytest.mark.parametrize('args, named', [
    (['--mocap-topic', 'external/pose', '--mocap-frame', 'z_up'], "--mocap-frame = 'z_up' refused"),
    (['--mocap-topic', 'external/pose', '--mocap-rate-hz', '200'], '--mocap-rate-hz = 200.0 refused: at most '
                                                                    '--loop-rate-hz (100.0)'),
    (['--mocap-topic', 'external/pose', '--mocap-latency-s', '-1'], 'mocap latency_s = -1.0 refused'),
    (['--mocap-frame', 'y_up'], "--mocap-frame = 'y_up' refused: needs --mocap-topic"),
])
def test_bad_mocap_options_exit_2_naming_them(capsys, args, named):
    assert main([*args, '--url', 'udpout:127.0.0.1:9', '--duration-s', '1']) == 2   # accepted: runs 1 s, exit 0
    assert named in capsys.readouterr().err
