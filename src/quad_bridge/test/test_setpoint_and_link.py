"""Setpoint checks (NaN/inf refused, tilt clamped keeping yaw) and the link state machine."""

import math
import re

import numpy as np
import pytest

from quad_bridge.link import LinkState, RateMeter, is_vehicle_heartbeat
from quad_bridge.setpoint import check_setpoint, clamp_tilt, tilt_rad
from quad_common import rotations
from quad_common.signing_key import load_signing_key
from quad_common.types import AttitudeSetpoint


@pytest.mark.parametrize('field, sp', [
    ('quaternion', AttitudeSetpoint(quaternion=np.array([np.nan, 0, 0, 1.0]))),
    ('specific_force_mps2', AttitudeSetpoint(specific_force_mps2=math.inf)),
    ('specific_force_mps2', AttitudeSetpoint(specific_force_mps2=-1.0)),
    ('body_rates', AttitudeSetpoint(body_rates=np.array([0.0, math.nan, 0.0]))),
])
def test_non_finite_setpoints_are_refused_naming_the_field(field, sp):
    with pytest.raises(ValueError, match=field):
        check_setpoint(sp, math.radians(35.0))


def test_tilt_within_limit_passes_unchanged():
    q = rotations.from_euler(0.2, -0.1, 1.0)
    sp, clamped, _ = check_setpoint(AttitudeSetpoint(quaternion=q, specific_force_mps2=12.0), math.radians(35.0))
    assert not clamped
    np.testing.assert_allclose(sp.quaternion, q)
    assert sp.specific_force_mps2 == 12.0


def test_over_tilt_is_clamped_keeping_yaw_and_tilt_direction():
    q = rotations.from_euler(math.radians(60.0), 0.0, math.radians(40.0))
    q_c, clamped = clamp_tilt(q, math.radians(35.0))
    assert clamped
    assert math.degrees(tilt_rad(q_c)) == pytest.approx(35.0)
    z_before, z_after = rotations.to_matrix(q)[:, 2], rotations.to_matrix(q_c)[:, 2]
    heading = lambda z: math.atan2(z[1], z[0])  # noqa: E731
    assert heading(z_after) == pytest.approx(heading(z_before))
    x_after = rotations.to_matrix(q_c)[:, 0]
    x_before = rotations.to_matrix(q)[:, 0]
    assert math.atan2(x_after[1], x_after[0]) == pytest.approx(math.atan2(x_before[1], x_before[0]), abs=0.2)
    # a pure roll to 60 deg becomes a pure roll to 35 deg at the same yaw
    roll, pitch, yaw = rotations.to_euler(q_c)
    assert (math.degrees(roll), math.degrees(pitch), math.degrees(yaw)) == pytest.approx((35.0, 0.0, 40.0), abs=1e-6)


def test_link_state_machine():
    link = LinkState(link_timeout_s=1.0)
    assert link.state == LinkState.WAITING and link.update(5.0) is None
    assert link.heartbeat(10.0) == 'connected'
    assert link.heartbeat(10.9) is None
    assert link.update(11.8) is None
    assert link.update(12.0) == 'lost' and link.state == LinkState.LOST
    assert link.update(13.0) is None                      # reported once
    assert link.heartbeat(14.0) == 'reconnected'
    assert (link.losses, link.reconnects, link.state) == (1, 1, LinkState.UP)


def test_a_receive_thread_that_is_behind_never_declares_a_live_link_lost():
    """A busy companion computer: the receive thread last read the vehicle at 10.0 s and has not drained the
    link since (it is behind or not scheduled): at 12.5 s, past link_timeout_s by the clock, nothing is declared;
    once it has drained past the deadline with nothing more from the vehicle, the loss is; telemetry between
    heartbeats keeps the link alive by itself."""
    link = LinkState(link_timeout_s=2.0)
    link.heartbeat(10.0)
    assert link.update(12.5, drained_s=10.0) is None        # the old verdict: 'lost' (2.5 s without a heartbeat)
    assert link.update(12.6, drained_s=11.9) is None
    assert link.update(12.7, drained_s=12.1) == 'lost'
    live = LinkState(link_timeout_s=1.0)
    live.heartbeat(0.0)
    for k in range(1, 150):                                 # 50 Hz telemetry, no second heartbeat for 3 s
        live.message(0.02 * k, k % 256)
        assert live.update(0.02 * k, drained_s=0.02 * k) is None


def test_packet_loss_from_sequence_numbers():
    """2 of 302 packets lost; a duplicate and a late packet lose nothing (pymavlink's count: each ~255 lost),
    and the 8-bit wrap is no loss."""
    link = LinkState(link_timeout_s=1.0)
    link.heartbeat(0.0)
    seqs = [k % 256 for k in range(300)]
    del seqs[100], seqs[200]                                # two lost
    seqs.insert(50, seqs[49])                               # a duplicate
    seqs[150], seqs[151] = seqs[151], seqs[150]             # two swapped: one late
    for seq in seqs:
        link.message(0.0, seq)
    assert link.sequence.reordered == 2
    assert link.packet_loss_pct() == pytest.approx(100 * 3 / (len(seqs) + 3))   # the swap counts its gap once


def test_vehicle_heartbeats_and_autopilot_choice():
    assert is_vehicle_heartbeat(2, 12)                    # quadrotor, PX4
    assert not is_vehicle_heartbeat(6, 8)                 # GCS
    assert not is_vehicle_heartbeat(18, 8)                # onboard controller
    assert not is_vehicle_heartbeat(26, 3)                # gimbal


def test_rate_meter():
    meter = RateMeter(window_s=1.0)
    for k in range(100):
        meter.tick(k * 0.02)
    assert meter.rate_hz(1.98) == pytest.approx(50.0, abs=1.0)
    assert meter.rate_hz(10.0) == 0.0


def test_signing_key_file(tmp_path):
    hex_key = tmp_path / 'hex.key'
    hex_key.write_text('00' * 31 + 'ff\n')
    assert load_signing_key(str(hex_key)) == bytes(31) + b'\xff'
    phrase = tmp_path / 'phrase.key'
    phrase.write_text('correct horse')
    assert len(load_signing_key(str(phrase))) == 32
    empty = tmp_path / 'empty.key'
    empty.write_text('')
    with pytest.raises(ValueError, match='empty'):
        load_signing_key(str(empty))


def test_the_float_path_of_check_setpoint_gives_what_the_numpy_path_gives(monkeypatch):
    """check_setpoint's shortcut for a valid setpoint within max_tilt (quad_bridge.setpoint._within_tilt) against
    the numpy path it skips, on setpoints either side of the limit, with and without body rates."""
    import quad_bridge.setpoint as setpoint

    rng = np.random.default_rng(7)
    cases = [AttitudeSetpoint(quaternion=q, specific_force_mps2=float(f), body_rates=rates)
             for q, f, rates in zip(rng.normal(size=(400, 4)) * [0.3, 0.3, 1.0, 1.0], rng.uniform(0, 30, 400),
                                    [None, np.array([0.1, -0.2, 0.3])] * 200)]
    fast = [check_setpoint(sp, math.radians(35), 40.0) for sp in cases]
    assert sum(not clamped for _, clamped, _ in fast) > 100   # the shortcut was taken
    monkeypatch.setattr(setpoint, '_within_tilt', lambda sp, max_tilt_rad: None)
    for sp, (a, clamped, kept) in zip(cases, fast):
        b, clamped_b, kept_b = check_setpoint(sp, math.radians(35), 40.0)
        assert (clamped, kept) == (clamped_b, kept_b)
        assert np.array_equal(a.quaternion, b.quaternion) and a.specific_force_mps2 == b.specific_force_mps2
        assert (a.body_rates is None) == (b.body_rates is None)
        assert a.body_rates is None or np.array_equal(a.body_rates, b.body_rates)


def _serialized(q, f, rates=None, frame_id='base_link', q_unset=False, f_unset=False):
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import Imu

    msg = Imu()
    msg.header.frame_id = frame_id
    msg.orientation.x, msg.orientation.y, msg.orientation.z, msg.orientation.w = map(float, q)
    msg.linear_acceleration.z = float(f)
    if rates is None:
        msg.angular_velocity_covariance[0] = -1.0
    else:
        msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z = map(float, rates)
    msg.orientation_covariance[0] = -1.0 if q_unset else 0.0
    msg.linear_acceleration_covariance[0] = -1.0 if f_unset else 0.0
    return serialize_message(msg)


def test_the_float_path_from_cdr_gives_what_imu_to_setpoint_and_check_setpoint_give():
    """setpoint_from_cdr against cdr.imu_to_setpoint + check_setpoint: the same values, bit for bit,
    the same clamping and the same errors, for setpoints within the tilt limit and beyond, with and without body
    rates, frame ids of every alignment, unset fields, NaN, inf, a zero quaternion and a negative thrust."""
    from quad_bridge.setpoint import setpoint_from_cdr
    from quad_common.ros import cdr

    rng = np.random.default_rng(7)
    cases = []
    for k in range(300):
        q = rotations.from_euler(*rng.normal(scale=0.5, size=3)) * rng.uniform(0.5, 2.0)
        rates = rng.normal(size=3) if k % 2 else None
        cases.append(_serialized(q, rng.uniform(0.0, 30.0), rates, frame_id='b' * (k % 9)))
    for bad in ([math.nan, 0, 0, 1], [0, 0, 0, 0], [math.inf, 0, 0, 1]):
        cases.append(_serialized(bad, 9.81))
    cases += [_serialized([0, 0, 0, 1], -1.0), _serialized([0, 0, 0, 1], math.nan),
              _serialized([0, 0, 0, 1], 9.81, [0.0, math.inf, 0.0]), _serialized([0, 0, 0, 1], 9.81, q_unset=True),
              _serialized([0, 0, 0, 1], 9.81, f_unset=True)]
    clamped = errors = 0
    for raw in cases:
        try:
            expected = check_setpoint(cdr.imu_to_setpoint(raw), math.radians(35.0), 25.0)
        except ValueError as exc:
            with pytest.raises(ValueError, match=re.escape(str(exc))):
                setpoint_from_cdr(raw, math.radians(35.0), 25.0)
            errors += 1
            continue
        (sp, was_clamped, kept), (sp0, clamped0, kept0) = setpoint_from_cdr(raw, math.radians(35.0), 25.0), expected
        assert (was_clamped, kept) == (clamped0, kept0)
        assert sp.quaternion.tolist() == sp0.quaternion.tolist() and sp.specific_force_mps2 == sp0.specific_force_mps2
        assert (sp.body_rates is None and sp0.body_rates is None) or sp.body_rates.tolist() == sp0.body_rates.tolist()
        clamped += was_clamped
    assert clamped > 20 and errors == 8
