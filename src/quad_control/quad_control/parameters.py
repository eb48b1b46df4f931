"""position_controller's parameters without ROS: the table the node declares (defaults from PositionGains and
quad_control.loop), the gains a set of values means, and the node's section of a params file (control profiles)."""

import numpy as np

from quad_common import mocap_frames
from quad_common.params import Param, parameters_of, params_content
from quad_control.controller_names import CONTROLLER_PARAM
from quad_control.loop import ENGAGE_DELAY_S, MAX_START_STEP_M, RATE_HZ
from quad_control.position import PositionGains

NODE_NAME = 'position_controller'
AXES = ('x', 'y', 'z')
SEED = PositionGains()
STATE_SOURCES = ('odom', 'external_pose')

SPECS = [
    CONTROLLER_PARAM,
    Param('rate_hz', RATE_HZ, 'control loop rate on the node clock; in lockstep 1 / sim lockstep_period_s',
          min=1.0, max=2000.0),
    Param('lockstep', False, 'compute the tick at t from the odometry stamped t (deferred until it arrives)'),
    Param('wait_for_trajectory', False, 'lockstep: defer the ticks (so simulated time waits) until a trajectory '
          'arrives; a late latched plan then never starts in the past'),
    Param('wait_for_engagement', True, 'advance a plan only while `vehicle/engaged` is true (the bridge\'s hand-over, '
          'the simulator at once); until then the setpoints hover where the vehicle is (docs/bridge.md); false: '
          'a plant that publishes no engagement (the plan runs on its stamp)', read_only=True),
    Param('engage_delay_s', ENGAGE_DELAY_S, 'at engagement a plan whose start has passed begins at least this '
          'long after it (the vehicle settles under our setpoints first; longer if the plan\'s own start delay is)',
          min=0.0, max=60.0),
    Param('max_start_step_m', MAX_START_STEP_M, 'a plan whose reference at its first tick is farther than this '
          'from the vehicle is refused (the controller keeps holding, ERROR on diagnostics naming the distance)',
          min=0.0, max=1000.0),
    Param('odom_timeout_s', 0.2, 'odometry older than this stops the setpoints (failsafe) and reports ERROR',
          min=0.001, max=10.0),
    Param('vehicle', 'config/vehicles/crazyflie.yaml', 'vehicle file: mass, thrust range, max tilt',
          read_only=True),
    Param('max_tilt_deg', 0.0, 'tilt limit of the command; 0 = the vehicle file max_tilt_deg', min=0.0, max=89.0),
    *[Param(f'kp_{a}', float(SEED.kp[i]), f'eq. 1 position gain, {a} axis (1/s^2)', min=0.0, max=1000.0)
      for i, a in enumerate(AXES)],
    *[Param(f'kd_{a}', float(SEED.kd[i]), f'eq. 1 velocity gain, {a} axis (1/s)', min=0.0, max=1000.0)
      for i, a in enumerate(AXES)],
    *[Param(f'ki_{a}', float(SEED.ki[i]), f'pid integral gain, {a} axis (1/s^3)', min=0.0, max=1000.0)
      for i, a in enumerate(AXES)],
    Param('integral_limit_mps2', SEED.integral_limit_mps2, 'anti-windup clamp on ki * integral, per axis (m/s^2)',
          min=0.0, max=100.0),
    Param('use_feedforward', True, 'reference acceleration in eq. 1 and jerk-based body rates in se3'),
    Param('attitude_lead_s', SEED.attitude_lead_s, 'attitude from a_des + lead * (reference jerk + drag x reference '
          'acceleration: the feed-forward lead later), cancelling the onboard attitude loop lag (about kd/kp of '
          'eq. 6 = 0.1 s); 0 = off (the seed)', min=0.0, max=1.0),
    Param('thrust_scale', SEED.thrust_scale, 'delivered / commanded specific force of the vehicle (quadflight '
          'identify); the thrust command is divided by it; 1 = the seed', min=0.5, max=2.0),
    Param('disturbance_time_constant_s', SEED.disturbance_time_constant_s, 'filter time constant of the observed '
          'external acceleration (drag, wind) subtracted from a_des; 0 = off (the seed)', min=0.0, max=10.0),
    Param('drag_feedforward_per_s', SEED.drag_feedforward_per_s, 'linear air drag of the vehicle (1/s: drag '
          'deceleration per m/s; quadflight identify measures it): the plan\'s drag D * reference velocity is added '
          'to the feed-forward; 0 = off (the seed)', min=0.0, max=10.0),
    Param('drag_learning_time_s', SEED.drag_learning_time_s, 'learn the horizontal drag D online (quad_control.'
          'drag_estimate: the observed external acceleration regressed on the velocity while the plan moves), '
          'starting from drag_feedforward_per_s, kept in [0, 3] 1/s; the forgetting time of the fit (s of flight '
          'at >= 0.3 m/s); 0 = off (the seed: D = drag_feedforward_per_s)', min=0.0, max=600.0),
    Param('velocity_from_position_s', SEED.velocity_from_position_s, 'the velocity the controller flies follows '
          'the odometry\'s own position (its derivative) below 1 / (2 pi tau) and its velocity above (a '
          'complementary filter, quad_control.velocity_blend): an autopilot estimate whose velocity wanders apart '
          'from its position (PX4 EKF2); 0 = the odometry\'s velocity (the seed)', min=0.0, max=10.0),
    Param('state_source', 'odom', 'the state the controller flies from: odom (the vehicle\'s estimate: the simulator, '
          'the bridge) or external_pose (motion capture on external/pose: velocity by quad_control.pose_state\'s '
          'alpha-beta filter)', choices=STATE_SOURCES, read_only=True),
    Param('external_pose_frame', 'enu', 'state_source external_pose: frame of the pose, enu (ENU world, FLU body) '
          '| y_up (motion-capture Y-up, quad_common.mocap_frames)', choices=mocap_frames.FRAMES, read_only=True),
    Param('pose_position_noise_m', 0.001, 'state_source external_pose: the pose\'s position noise, RMS per axis (m)',
          min=1e-6, max=1.0),
    Param('pose_acceleration_mps2', 5.0, 'state_source external_pose: the acceleration the vehicle may do '
          'unannounced (m/s^2): higher follows faster, lower smooths more (the filter\'s tracking index)',
          min=0.01, max=100.0),
    Param('realtime_priority', 0, 'the tick\'s threads (the executor\'s, Fast DDS\'s) under SCHED_FIFO at this '
          'priority (1..99), the trajectory decoder left ordinary; 0 = off (the ordinary scheduler)', min=0, max=99,
          read_only=True),
]


def gains_from(values: dict) -> PositionGains:
    """PositionGains from position_controller parameters (kp_x ... disturbance_time_constant_s); a missing one
    keeps the seed's value."""
    seed = PositionGains()

    def axes(name):
        return np.array([values.get(f'{name}_{a}', getattr(seed, name)[i]) for i, a in enumerate('xyz')], dtype=float)

    return PositionGains(kp=axes('kp'), kd=axes('kd'), ki=axes('ki'),
                         integral_limit_mps2=float(values.get('integral_limit_mps2', seed.integral_limit_mps2)),
                         use_feedforward=bool(values.get('use_feedforward', seed.use_feedforward)),
                         attitude_lead_s=float(values.get('attitude_lead_s', seed.attitude_lead_s)),
                         disturbance_time_constant_s=float(values.get('disturbance_time_constant_s',
                                                                      seed.disturbance_time_constant_s)),
                         thrust_scale=float(values.get('thrust_scale', seed.thrust_scale)),
                         drag_feedforward_per_s=float(values.get('drag_feedforward_per_s',
                                                                 seed.drag_feedforward_per_s)),
                         drag_learning_time_s=float(values.get('drag_learning_time_s', seed.drag_learning_time_s)),
                         velocity_from_position_s=float(values.get('velocity_from_position_s',
                                                                   seed.velocity_from_position_s)))


def profile_parameters(content: dict) -> dict:
    """position_controller's parameters in a params file's content ({} when it sets none)."""
    return parameters_of(content, NODE_NAME)


def profile_content(values: dict) -> dict:
    """A params file's content (a control profile) setting `values` on position_controller."""
    return params_content(NODE_NAME, values)


def profile_with(content: dict, values: dict) -> dict:
    """A control profile's content with `values` set over its position_controller parameters (content itself
    unchanged): a variant of a shipped profile."""
    return profile_content({**profile_parameters(content), **values})
