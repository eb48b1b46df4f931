"""The real-vehicle chain flown offline: quad_vehicle_emu's own pieces (its vehicle with SIH's drag, the attitude
shaping behind the autopilot's loop, the estimate; the telemetry delay line) under position_controller's ControlLoop
through the flight harness (quad_bringup.offline.harness.fly), without processes, MAVLink or a loaded machine. It stands
for the emulator run with the flags it is given (PX4_SIH_LIKE, PX4_SIH_BEFORE, PX4_SIH_FITTED: the same tuples the
bridge flights hand quad_vehicle_emu.mavlink_vehicle), so an emulated flight's RMSE can be told apart from what
processes and load add. Scored as `quadflight report` scores a bag (score). Used by the bridge and indoor-flight
benches."""

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from quad_bringup.offline.harness import DelayLine as HarnessDelayLine
from quad_bringup.offline.harness import Mocap, fly
from quad_common import rotations
from quad_common.paths import resolve_config
from quad_common.types import State
from quad_common.vehicle import load_vehicle
from quad_common.yaml_io import load_yaml
from quad_control.loop import ControlLoop
from quad_control.parameters import gains_from, profile_parameters
from quad_control.plugins import make_controller
from quad_control.pose_state import PoseStateFilter
from quad_control.position import Limits
from quad_sim.mocap import MocapConfig
from quad_trajectory import planner
from quad_trajectory.mission import SAMPLE_RATE_HZ
from quad_vehicle_emu.attitude import DelayLine
from quad_vehicle_emu.estimator import SIH_VELOCITY_NOISE_MPS, WANDER_SMOOTHING_PX4_SIH_S
from quad_vehicle_emu.plant import VisionFeed, plant_flags, plant_from_flags

CONTROL = str(resolve_config('config/control.yaml'))                   # the seed profile every profile is laid over
VEHICLE_FILE = str(resolve_config('config/vehicles/px4_quad.yaml'))    # the emulator's vehicle
SQUARE = [(0.0, 0.0, 2.0), (3.0, 0.0, 2.0), (3.0, 3.0, 2.0), (0.0, 3.0, 2.0), (0.0, 0.0, 2.0)]   # docs/bridge.md's
SPEED_MPS = 0.8
# PX4 v1.16 SIH as measured on it: attitude lag 0.23 s (tau = 0.23 - 1 / 6.5, quad_vehicle_emu.attitude);
# the estimate 0.4-0.8 m RMS off the truth (height 0.3-1.3 m), wandering 0.5 m a minute, 0.15 s behind; its clock
# at 0.984-0.993 of wall time; and SIH's own airframe: SIH_KDV 1.0 N/(m/s) on SIH_MASS 1.0 kg (sih_params.yaml)
# Beside them, from PX4's source (docs/emulator.md "PX4 SIH's attitude chain and velocity noise"): SIH's airframe
# under PX4's default rate loop (12.7 rad/s behind SIH_T_TAU 0.05 s motors), roll/pitch rates dropped from a
# SET_ATTITUDE_TARGET that sets the attitude (mavlink_receiver.cpp), the output predictor's velocity noise from
# SIH's accelerometer noise over EKF2_TAU_VEL
PX4_SIH_BEFORE = ('--attitude-tau-s', '0.076', '--estimator-lag-s', '0.15', '--estimator-wander-m', '0.6',
                  '--estimator-wander-z-m', '0.8', '--estimator-wander-tau-s', '60', '--clock-rate', '0.985',
                  '--drag-per-s', '1.0')
PX4_SIH_LIKE = (*PX4_SIH_BEFORE, '--rate-loop', 'px4-sih', '--rp-rates-with-attitude', 'ignored',
                '--estimator-velocity-noise-mps', ','.join(f'{v:.4f}' for v in SIH_VELOCITY_NOISE_MPS))
# PX4 v1.16 SIH fitted to the four exported flights' measured properties (docs/emulator.md "PX4 SIH fitted"):
# attitude response tau 0.15 s behind a 0.105 s dead time (default loop + 0.05 s shaping + 0.07 s dead time fits
# so), the estimate's error as measured (position std 0.1-0.4 m over 3-6 s, its spectrum's fall above 0.5 Hz,
# velocity 0.1-0.32 m/s over 2-5 s), and current: EKF2's logged estimate at its timestamp_sample is the truth then,
# no lag (the first guess, 0.15 s, is not in PX4's log; docs/emulator.md "PX4 SIH fitted")
PX4_SIH_FITTED = ('--attitude-tau-s', '0.05', '--attitude-dead-time-s', '0.07', '--estimator-lag-s', '0',
                  '--estimator-wander-m', '0.18', '--estimator-wander-z-m', '0.3', '--estimator-wander-tau-s', '4',
                  '--estimator-wander-smoothing-s', str(WANDER_SMOOTHING_PX4_SIH_S),
                  '--estimator-velocity-wander-mps', '0.2', '--estimator-velocity-wander-z-mps', '0.15',
                  '--estimator-velocity-wander-tau-s', '3', '--clock-rate', '0.992', '--drag-per-s', '1.0',
                  '--rp-rates-with-attitude', 'ignored',
                  '--estimator-velocity-noise-mps', ','.join(f'{v:.4f}' for v in SIH_VELOCITY_NOISE_MPS))

# control_real.yaml as PX4 SIH flew it (the shared flights real1-5: the project at 95a3098, before the velocity
# blend, the drag and the retuned ki), and PX4 v1.16.0 SIH's estimate against the plan on the shared flights (RMSE,
# m, scored on PX4's own log: pd1-3, real2-5, se3_1-3)
AS_FLOWN_ON_PX4_SIH = {'controller': 'pid', 'kp_x': 2.0, 'kp_y': 2.0, 'kp_z': 6.0, 'kd_x': 2.5, 'kd_y': 2.5,
                       'kd_z': 4.0, 'ki_x': 1.0, 'ki_y': 1.0, 'ki_z': 3.0, 'integral_limit_mps2': 2.0,
                       'attitude_lead_s': 0.19, 'disturbance_time_constant_s': 0.0}
PX4_SIH_ESTIMATE_VS_PLAN_M = {'seed pd (control.yaml)': (0.41, 0.55), 'control_real as PX4 SIH flew it': (0.445, 0.70),
                              'control_se3.yaml (se3)': (0.23, 0.25)}

HOVER_S = 15.0   # hovering before the plan, as the graph does while the bridge connects
ODOM_EARLY_MAX_S = 1.0   # stamps at most this early (the old filter: drift x 10 s window; 0.93 under load: 0.75 s)


def _profile_values(profile):
    """position_controller's parameters: CONTROL, then `profile` (a path resolve_config finds) over it."""
    content = load_yaml(CONTROL)
    params = content['position_controller']['ros__parameters']
    if profile:
        params.update(load_yaml(str(resolve_config(profile)))['position_controller']['ros__parameters'])
    params['vehicle'] = VEHICLE_FILE
    return profile_parameters(content)


def odom_early_s_checked(early_s) -> float:
    """The odometry stamps' bias (s early) of fly_chain_offline: finite, 0..ODOM_EARLY_MAX_S."""
    early_s = float(early_s)
    if not (math.isfinite(early_s) and 0.0 <= early_s <= ODOM_EARLY_MAX_S):
        raise ValueError(f'odometry stamps {early_s!r} s early: must be within 0..{ODOM_EARLY_MAX_S} s '
                         '(0: stamped when measured, as the bridge stamps now)')
    return early_s


def score(stamps_s, positions, traj, hover_s: float = HOVER_S) -> float:
    """The RMSE as `quadflight report` scores it (quad_bringup.analysis.metrics.compute_metrics): each odometry's
    position against the plan at its own header stamp (the plan starts at hover_s), over the stamps in the plan plus
    3 s."""
    stamps_s, positions = np.asarray(stamps_s), np.asarray(positions)
    scored = (stamps_s >= hover_s) & (stamps_s <= hover_s + traj.duration_s + 3.0)
    plan_t = np.arange(traj.position.shape[0]) / SAMPLE_RATE_HZ
    at = np.clip(stamps_s[scored] - hover_s, 0.0, plan_t[-1])
    ref = np.column_stack([np.interp(at, plan_t, traj.position[:, i]) for i in range(3)])
    return float(np.sqrt(np.mean(np.sum((positions[scored] - ref) ** 2, axis=1))))


def fly_chain_offline(profile, seed, velocity_lag_s=0.0, options=PX4_SIH_LIKE, odom_early_s=None,
                      mocap=None, truth=False, vision=None, waypoints=SQUARE, speed_mps: float = SPEED_MPS,
                      hover_s: float = HOVER_S) -> float:
    """The RMSE of chain_flight (its other arguments): of the estimate, or with `truth` of the truth (where the vehicle
    is, every 10 ms) against the plan."""
    flight = chain_flight(profile, seed, velocity_lag_s, options, odom_early_s, mocap, vision, waypoints, speed_mps,
                          hover_s)
    return flight.truth_rmse_m if truth else flight.rmse_m


@dataclass
class ChainFlight:
    """What fly_chain_offline scores, with what the vehicle did from the plan's start to its end + 3 s."""
    rmse_m: float                 # the estimate (the odometry) against the plan
    tilt_deg: np.ndarray          # the vehicle's tilt every 10 ms
    counts: dict                  # ControlLoop's counters over the whole flight (saturation_tilt, ...)
    track: tuple                  # (times s, positions) of the truth after each 10 ms period
    traj: object                  # the plan (sampled) and when it started
    hover_s: float

    @cached_property
    def truth_rmse_m(self) -> float:
        """The truth (where the vehicle is, every 10 ms) against the plan, scored as the estimate is."""
        return score(*self.track, self.traj, self.hover_s)

    def describe(self) -> str:
        saturated = {k: v for k, v in self.counts.items() if k.startswith('saturation') and v}
        return (f'RMSE {self.rmse_m:.3f} m, tilt {np.median(self.tilt_deg):.1f} deg median, std '
                f'{np.std(self.tilt_deg):.1f}, max {np.max(self.tilt_deg):.1f}; saturated ticks {saturated or "none"}')


def chain_flight(profile, seed, velocity_lag_s=0.0, options=PX4_SIH_LIKE, odom_early_s=None,
                 mocap=None, vision=None, waypoints=SQUARE, speed_mps: float = SPEED_MPS,
                 hover_s: float = HOVER_S) -> ChainFlight:
    """The PX4 SIH-like emulated chain without processes, MAVLink or a loaded machine: the emulator's own pieces
    (quad_vehicle_emu.plant: its vehicle with SIH's drag, the attitude shaping behind the autopilot's loop, the
    estimate; the telemetry delay line at 20 ms and 50 Hz) through the flight harness (quad_bringup.offline.harness:
    position_controller's ControlLoop) at 100 Hz, `waypoints` (default the 3 m square) at speed_mps planned as
    trajectory_node plans it and started after hover_s of hover; the RMSE of the estimate (what the bag's odometry
    is) against the plan, over the plan plus 3 s.
    velocity_lag_s: the estimate's velocity that late too (the first SIH-like model).
    options: the emulator's flags it stands for (PX4_SIH_LIKE, or PX4_SIH_BEFORE).
    odom_early_s: None scores each odometry at its arrival (20 ms after it was measured; the rows in
    docs/emulator.md); a number stamps it as the bridge does, when it was measured on the vehicle's clock, that many
    seconds early (0..ODOM_EARLY_MAX_S; the bridge's clock fallback on PX4 SIH: 0.07-0.15 s). Either
    stamp reaches the controller as position_controller's odometry stamp (the loop runs as the node does under the
    bridge, lockstep false: a tick controls from the newest odometry, whatever its stamp) and the scoring (score:
    the plan at the stamp, as `quadflight report` does).
    mocap: None, or (noise_m, latency_s, rate_hz): the controller flies from motion capture (position_controller's
    state_source external_pose: quad_bringup.offline.harness.Mocap, the simulator's stand-in at rate_hz with that noise
    and latency, through quad_control.pose_state's filter with the profile's pose parameters) instead of the odometry.
    vision: None, or (noise_m, age_s, rate_hz, delay_ms): the autopilot's estimate is fused from a motion-capture
    pose (quad_vehicle_emu.plant.VisionFeed: the simulator's stand-in at rate_hz with that noise, reaching PX4 age_s
    later, fused as quad_vehicle_emu.external_vision does with EKF2_EV_DELAY = delay_ms) on every axis; the
    controller flies the odometry as without it."""
    early_s = None if odom_early_s is None else odom_early_s_checked(odom_early_s)
    values = _profile_values(profile)
    vehicle = load_vehicle(VEHICLE_FILE)
    loop = ControlLoop(make_controller(values.get('controller', 'pd'), gains_from(values), vehicle, Limits.of(vehicle),
                                       100.0), 100.0)
    plan = planner.plan(np.array(waypoints), 0.0, planner.PlanOptions(speed_mps=speed_mps), vehicle=vehicle)
    traj = plan.trajectory.to_sampled(SAMPLE_RATE_HZ)
    loop.set_trajectory(int(hover_s * 1e9), traj)
    start = ','.join(map(str, waypoints[0]))
    flags = plant_flags((*options, '--vehicle', VEHICLE_FILE, '--initial-position', start, '--seed', str(seed)))
    feed = None
    if vision is not None:
        vision_noise_m, vision_age_s, vision_rate_hz, vision_delay_ms = vision
        feed = VisionFeed('px4', MocapConfig(rate_hz=vision_rate_hz, position_noise_m=vision_noise_m,
                                             latency_s=vision_age_s), vision_delay_ms, seed)
    late = (lambda estimate: _LateVelocity(estimate, velocity_lag_s)) if velocity_lag_s else None
    plant = plant_from_flags(flags, rp_rates_fed=flags.rp_rates_with_attitude == 'fed', vision=feed,
                             estimate_wrapper=late)
    plant.sim.armed = True
    if mocap is not None:
        mocap_noise_m, mocap_latency_s, mocap_rate_hz = mocap
        telemetry = Mocap(MocapConfig(rate_hz=mocap_rate_hz, position_noise_m=mocap_noise_m,
                                      latency_s=mocap_latency_s),
                          PoseStateFilter(values.get('pose_position_noise_m', 0.001),
                                          values.get('pose_acceleration_mps2', 2.0), 0.2), seed)
    else:   # odometry at 50 Hz, 20 ms late, stamped at its arrival or when measured (early_s before)
        telemetry = HarnessDelayLine(0.02, 2, stamp_shift_s=0.02 if early_s is None else -early_s)
    end_s = hover_s + traj.duration_s + 3.0
    flown = fly(loop, plant, telemetry, int(end_s * 100) + 1)
    t_s, states = flown.track()
    in_plan = [s for t, s in zip(t_s, states) if hover_s <= t <= end_s]
    tilt_deg = np.degrees([math.acos(min(1.0, rotations.to_matrix(s.quaternion)[2, 2])) for s in in_plan])
    odometry_rmse_m = score([stamp_ns * 1e-9 for stamp_ns, _ in flown.odometry],
                            [state.position for _, state in flown.odometry], traj, hover_s)
    track = (t_s[1:], [s.position for s in states[1:]])   # where the vehicle is after each period
    return ChainFlight(odometry_rmse_m, tilt_deg, dict(loop.counts), track, traj, hover_s)


class _LateVelocity:
    """An Estimate whose velocity is the truth's lag_s ago (the first SIH-like model's estimate)."""

    def __init__(self, estimate, lag_s: float):
        self.estimate, self.velocities = estimate, DelayLine(lag_s)

    def fuse_vision(self, position_enu, fusion_time_s: float):
        self.estimate.fuse_vision(position_enu, fusion_time_s)

    def step(self, now_s, truth: State, vision_axes=(False, False, False)) -> State:
        est = self.estimate.step(now_s, truth, vision_axes)
        self.velocities.push(now_s, truth.velocity.copy())
        old = self.velocities.read(now_s)
        return State(position=est.position, velocity=old[1] if old else est.velocity, quaternion=est.quaternion,
                     body_rates=est.body_rates)
