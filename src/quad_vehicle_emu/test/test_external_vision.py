"""External vision in the emulated estimator (quad_vehicle_emu.external_vision, estimator.Estimate): the fusion
instant each autopilot gives a received pose, and the estimate that follows the poses, not the truth."""

import numpy as np
import pytest

from quad_common.types import State
from quad_vehicle_emu.estimator import Estimate
from quad_vehicle_emu.external_vision import (
    ARDUPILOT_HALF_EKF_STEP_US,
    PX4_CONVERGENCE_WINDOW,
    PX4_HALF_EKF_DT_US,
    JitterCorrection,
    Px4Timesync,
    VisionClock,
)

TICK_S = 0.01
ALL_AXES = (True, True, True)


def _truth(t_s, speed_mps=1.0):
    return State(position=np.array([speed_mps * t_s, 0.0, 1.0]), velocity=np.array([speed_mps, 0.0, 0.0]))


def _fly(estimate, clock, duration_s, pose_age_s, delay_ms, offset=(0.0, 0.0, 0.0), noise_m=0.0, speed_mps=1.0,
         pose_period_s=1.0 / 30.0, poses_until_s=np.inf, vision_axes=ALL_AXES, seed=0):
    """Ticks of TICK_S; a pose of the truth (+ offset, + noise) measured every pose_period_s, stamped at its
    measurement (boot time = this clock, us), arriving pose_age_s later and fused where `clock` says. Returns the
    times and the estimate's position error against the truth."""
    rng = np.random.default_rng(seed)
    in_flight, next_pose_s, times, errors = [], 0.0, [], []
    for k in range(int(round(duration_s / TICK_S))):
        now = k * TICK_S
        while next_pose_s <= now and next_pose_s < poses_until_s:
            measured = _truth(next_pose_s, speed_mps).position + offset + noise_m * rng.standard_normal(3)
            in_flight.append((next_pose_s + pose_age_s, next_pose_s, measured))
            next_pose_s += pose_period_s
        for _arrival, stamp, position in [s for s in in_flight if s[0] <= now]:
            fusion_us = clock.fusion_us(int(stamp * 1e6), int(now * 1e6), delay_ms)
            estimate.fuse_vision(position, fusion_us * 1e-6)
        in_flight = [s for s in in_flight if s[0] > now]
        truth = _truth(now, speed_mps)
        times.append(now)
        errors.append(estimate.step(now, truth, vision_axes).position - truth.position)
    return np.array(times), np.array(errors)


@pytest.mark.parametrize('flavour', ['px4', 'ardupilot'])
def test_with_the_delay_parameter_matching_the_poses_age_the_estimate_tracks_the_truth_within_the_pose_noise(
        flavour):
    """Flying at 1 m/s, poses 60 ms old with 1 cm noise, delay parameter 60 ms (less the half EKF step each
    autopilot subtracts itself): the estimate is within the noise of the truth; the same poses with the delay
    parameter 100 ms short of their age leave it 0.1 m behind (v x d)."""
    half_step_ms = (PX4_HALF_EKF_DT_US if flavour == 'px4' else ARDUPILOT_HALF_EKF_STEP_US) / 1000.0
    t, err = _fly(Estimate(), VisionClock(flavour), 6.0, 0.06, 60.0 - half_step_ms, noise_m=0.01)
    settled = err[t > 2.0]
    assert np.sqrt(np.mean(settled ** 2, axis=0)) == pytest.approx([0.0, 0.0, 0.0], abs=0.01)
    t, err = _fly(Estimate(), VisionClock(flavour), 6.0, 0.16, 60.0 - half_step_ms, noise_m=0.01)
    assert np.mean(err[t > 2.0, 0]) == pytest.approx(-0.1, abs=0.012)   # fused 0.1 s too late: behind by v d


def test_the_estimate_follows_the_pose_not_the_truth():
    """A rigid body 1 m off in x and 0.5 m in z: the estimate is 1 m and 0.5 m off, from the first pose on (the
    estimator resets its position to the pose when fusion starts), standing or flying."""
    for speed in (0.0, 1.0):
        t, err = _fly(Estimate(), VisionClock('ardupilot'), 3.0, 0.02, 19.0, offset=(1.0, 0.0, 0.5), speed_mps=speed)
        assert err[t > 0.1] == pytest.approx(np.tile([1.0, 0.0, 0.5], (int(np.sum(t > 0.1)), 1)), abs=0.01)


def test_only_the_vision_axes_follow_the_pose_and_the_gps_lag_and_wander_stay_off_them():
    """GPS-like lag 0.15 s and 0.5 m wander: on the vision axes (x, y) the estimate is the pose's, within 1 cm
    over 60 s; the height (baro / GPS) keeps the lag and wander."""
    estimate = Estimate(lag_s=0.15, wander_m=0.5, wander_z_m=0.5, tau_s=10.0, seed=4)
    t, err = _fly(estimate, VisionClock('px4'), 60.0, 0.0, 0.0, vision_axes=(True, True, False))
    assert np.max(np.abs(err[t > 1.0, :2])) < 0.01
    assert np.sqrt(np.mean(err[t > 1.0, 2] ** 2)) > 0.1


def test_when_the_poses_stop_the_estimate_dead_reckons_with_its_velocity_error():
    """Poses until 5 s: after them the correction is no longer renewed and the position integrates the published
    velocity's error (0.3 m/s RMS velocity wander here): a drift of tens of cm within the 5 s of EKF2_NOAID_TOUT,
    where with the poses it stayed within the bias that error leaves behind the blend (v_err x EKF2_TAU_POS)."""
    estimate = Estimate(velocity_wander_mps=0.3, velocity_wander_z_mps=0.0, velocity_wander_tau_s=3.0, seed=2)
    t, err = _fly(estimate, VisionClock('px4'), 10.0, 0.0, 0.0, poses_until_s=5.0)
    streaming = np.linalg.norm(err[(t > 1.0) & (t < 5.0), :2], axis=1)
    drift = np.linalg.norm(err[t > 9.5, :2], axis=1)
    assert np.max(streaming) < 0.12
    assert np.min(drift) > 0.3


def test_px4_reads_the_stamp_only_once_timesync_has_converged_then_in_the_companions_timesync_clock():
    """Timesync.cpp: the arrival time until 500 round trips under 10 ms; slower ones do not count. Then time_usec +
    the offset to the clock the companion answered TIMESYNC with: a stamp in that clock is fused at its own time;
    a stamp in PX4's boot time, with TIMESYNC answered in another clock, lands before boot."""
    sync = Px4Timesync()
    companion_ahead_us = 1_000_000_000   # the companion's TIMESYNC clock runs 1000 s ahead of PX4's boot clock
    now_us = 40_000_000
    for _ in range(20):   # 20 ms round trips: not used
        sync.update(now_us, (now_us - 10_000 + companion_ahead_us) * 1000, (now_us - 20_000) * 1000)
    assert sync.sequence == 0
    for _ in range(PX4_CONVERGENCE_WINDOW):
        assert sync.sync_stamp(123, now_us) == now_us   # not converged: the arrival, whatever the stamp
        now_us += 100_000
        sync.update(now_us, (now_us - 1000 + companion_ahead_us) * 1000, (now_us - 2000) * 1000)
    assert sync.converged and sync.offset_us == pytest.approx(-companion_ahead_us, abs=10)
    measured_us = now_us - 50_000
    assert sync.sync_stamp(measured_us + companion_ahead_us, now_us) == pytest.approx(measured_us, abs=10)
    clock = VisionClock('px4')
    clock.timesync = sync
    assert clock.fusion_us(measured_us, now_us, 0.0) < 0   # boot-time stamp + the companion offset


def test_ardupilot_takes_the_stamps_jitter_not_their_offset():
    """JitterCorrection: a constant offset between the stamp's clock and ArduPilot's is absorbed (the least lagged
    sample counts as arriving at once); a sample stamped 30 ms earlier than its arrival says is fused 30 ms
    earlier; VISO_DELAY_MS comes off on top."""
    jitter = JitterCorrection()
    for k in range(50):
        arrival = 10_000_000 + k * 33_000
        assert jitter.correct(arrival + 5_000_000_000 - 20_000, arrival) == arrival   # any clock, 20 ms lag
    arrival = 10_000_000 + 50 * 33_000
    assert jitter.correct(arrival + 5_000_000_000 - 50_000, arrival) == arrival - 30_000
    clock = VisionClock('ardupilot')
    assert clock.fusion_us(7, 2_000_000, 40.0) == 2_000_000 - 40_000 - ARDUPILOT_HALF_EKF_STEP_US
