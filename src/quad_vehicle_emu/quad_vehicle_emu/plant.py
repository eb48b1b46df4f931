"""The emulated autopilot's vehicle side, composed once (no MAVLink, no clock): quad_sim's Simulator flying
the vehicle as the emulator flies it (`attitude.emulated_vehicle`, linear air drag), the autopilot's attitude
response in front of it (`attitude.AttitudeResponse`: first order behind a dead time), roll/pitch rate
feed-forward dropped where the autopilot drops it (PX4's mavlink_receiver keeps only the yaw rate of a
SET_ATTITUDE_TARGET that carries an attitude), and the estimate its telemetry reports (`estimator.Estimate`),
fused from external-vision poses as the autopilot fuses them. The offline harness flies this class period by
period on the simulator's time, the emulator's real-time loop (mavlink_vehicle) tick by tick on its own clock
with the poses it receives. Both build it from the emulator's own flags (add_plant_arguments, plant_flags,
plant_from_flags): an offline flight that stands for an emulator run reads the very flags that run is given.

Each period T of the offline flight harness (quad_bringup.offline.harness):

    command(setpoint)      a new setpoint: the autopilot's target from now on
    advance(T)             respond(T): the target through the response into the simulator; advance_steps(T's
                           steps): physics; then the poses a VisionFeed (motion capture on every axis) delivered by
                           now are fused and the estimate steps at the simulator's time
    observed()             what the vehicle's telemetry sends now (the estimate, else the odometry)

Each tick of the emulator's real-time loop (quad_vehicle_emu.mavlink_vehicle), at its own clock's now:

    fuse_vision(p, t)      a pose received over MAVLink, fused as measured at t (external_vision.VisionClock)
    command(target), respond(dt)    the autopilot's target through the response; rest(q) instead when it
                           gives none (disarmed: the response at rest at q)
    advance_steps(n)       physics: the simulator caught up with now
    step_estimate(now, vision_axes)    the estimate at now, on the axes the autopilot takes from vision
"""

import argparse
import math

import numpy as np

from quad_common.paths import parameter_file
from quad_common.types import AttitudeSetpoint, State
from quad_sim.mocap import MocapConfig, MotionCapture
from quad_sim.simulator import Simulator
from quad_vehicle_emu.attitude import RATE_LOOPS, AttitudeResponse, default_tau_s, emulated_vehicle
from quad_vehicle_emu.drag import check_drag, with_linear_drag
from quad_vehicle_emu.estimator import OUTPUT_TAU_S, WANDER_SMOOTHING_PX4_SIH_S, Estimate
from quad_vehicle_emu.external_vision import VisionClock

PHYSICS_RATE_HZ = 500.0   # the emulator's physics rate (mavlink_vehicle --physics-rate-hz): its onboard loop's
DEFAULT_VEHICLE = 'vehicles/px4_quad.yaml'   # found as every file argument is (quad_common.paths)
# flags of the emulator that are not the plant's, accepted (and left alone) by plant_flags
NOT_PLANT_FLAGS = ('--clock-rate',)


def triple(text):
    """argparse type: 'x,y,z', three finite numbers."""
    values = [float(v) for v in text.split(',')]
    if len(values) != 3 or not all(map(math.isfinite, values)):
        raise argparse.ArgumentTypeError(f'needs 3 finite numbers x,y,z, got {text!r}')
    return values


def add_plant_arguments(ap: argparse.ArgumentParser):
    """The emulator's flags that make its plant (plant_from_flags): the vehicle, its attitude response behind the
    autopilot's loop, its air drag, the estimate, the physics rate."""
    ap.add_argument('--vehicle', default=DEFAULT_VEHICLE,
                    help='vehicle YAML (quad_common.vehicle): a path, or one under config/ (installed or the checkout)')
    ap.add_argument('--initial-position', type=triple, default=[0.0, 0.0, 0.0],
                    help='x,y,z in map (ENU), m; above the floor: starts armed, holding (AUTO.LOITER / LOITER)')
    ap.add_argument('--initial-yaw', type=float, default=0.0, help='rad, ENU')
    ap.add_argument('--attitude-tau-s', type=float, default=None,
                    help='attitude shaping time constant; default: what makes the roll/pitch lag 0.19 s on the '
                    "autopilot's loop (0.036 s; ArduCopter SITL measured 0.17-0.21 s), 0 when the vehicle file "
                    "sets quad_sim's attitude_loop to an autopilot-like one itself (so3_pd, lag)")
    ap.add_argument('--attitude-dead-time-s', type=float, default=0.0,
                    help='the attitude target is acted on this late, before the shaping (PX4 SIH measured 0.09-0.11 '
                    's before a 0.15 s first order: --attitude-tau-s 0 --attitude-dead-time-s 0.1 with --rate-loop '
                    'px4-sih); default 0')
    ap.add_argument('--estimator-lag-s', type=float, default=0.0,
                    help="its position estimate trails the truth this much (velocity is now; PX4 SIH's logs: 0)")
    ap.add_argument('--estimator-wander-m', type=float, default=0.0,
                    help="RMS of the estimate's horizontal position wander per axis (PX4 SIH: 0.4-0.8 m off)")
    ap.add_argument('--estimator-wander-z-m', type=float, default=0.0,
                    help="RMS of the estimate's height wander (PX4 SIH: 0.3-1.3 m)")
    ap.add_argument('--estimator-wander-tau-s', type=float, default=60.0,
                    help="the wander's correlation time (PX4 SIH: about 0.5 m a minute)")
    ap.add_argument('--estimator-wander-smoothing-s', type=float, default=OUTPUT_TAU_S,
                    help="the wander's first-order smoothing (default EKF2_TAU_POS 0.25 s; PX4 SIH's error spectrum: "
                         f'{WANDER_SMOOTHING_PX4_SIH_S})')
    ap.add_argument('--estimator-velocity-noise-mps', type=triple, default=[0.0, 0.0, 0.0], metavar='X,Y,Z',
                    help="RMS of the estimate's velocity noise on the body axes, correlated over EKF2_TAU_VEL "
                         '(PX4 SIH: 0.0125,0.0425,0.035 from its accelerometer noise); default none')
    ap.add_argument('--rate-loop', choices=tuple(RATE_LOOPS), default='default',
                    help="the autopilot's roll/pitch rate loop: default 60 rad/s; px4-sih: PX4's defaults on SIH's "
                         'airframe (12.7 rad/s behind 0.05 s motors; quad_vehicle_emu.attitude)')
    ap.add_argument('--rp-rates-with-attitude', choices=('fed', 'ignored'), default='fed',
                    help='PX4: roll/pitch rates of a SET_ATTITUDE_TARGET that sets the attitude: fed forward '
                         "(default) or ignored as PX4's mavlink_receiver does (yaw rate kept)")
    ap.add_argument('--estimator-velocity-wander-mps', type=float, default=0.0,
                    help="RMS of the estimate's slow horizontal velocity error per axis (PX4 SIH: 0.1-0.32 m/s)")
    ap.add_argument('--estimator-velocity-wander-z-mps', type=float, default=0.0,
                    help="RMS of the estimate's slow vertical velocity error (PX4 SIH: 0.14-0.19 m/s)")
    ap.add_argument('--estimator-velocity-wander-tau-s', type=float, default=3.0,
                    help="the velocity error's correlation time (PX4 SIH: 2-5 s)")
    ap.add_argument('--drag-per-s', type=float, default=0.0,
                    help='linear air drag, m/s^2 per m/s on every axis (PX4 SIH: SIH_KDV / SIH_MASS = 1.0); 0: none')
    ap.add_argument('--seed', type=int, default=0)
    ap.add_argument('--physics-rate-hz', type=float, default=PHYSICS_RATE_HZ)


def plant_flags(flags) -> argparse.Namespace:
    """The plant's flags (add_plant_arguments) from a tuple of the emulator's flags, as the emulator reads them;
    ValueError naming a flag that is neither the plant's nor in NOT_PLANT_FLAGS."""
    parser = argparse.ArgumentParser(prog='quad_vehicle_emu plant', add_help=False, allow_abbrev=False)
    add_plant_arguments(parser)
    args, rest = parser.parse_known_args([str(f) for f in flags])
    unknown = [f for f in rest[::2] if f not in NOT_PLANT_FLAGS]
    if unknown or len(rest) % 2:
        raise ValueError(f'emulator flags {rest!r}: {unknown[0] if unknown else rest[-1]!r} is no plant flag')
    return args


def plant_from_flags(args, rp_rates_fed: bool = True, vision=None, vision_timeout_s: float | None = None,
                     estimate_now: bool = True, estimate_wrapper=None) -> 'AutopilotPlant':
    """The AutopilotPlant the emulator flies with these flags (add_plant_arguments): the vehicle file through the
    autopilot's rate loop with its linear air drag, in the simulator (no setpoint timeout: the autopilot's modes
    decide), the attitude response (--attitude-tau-s, default default_tau_s), the estimate. rp_rates_fed False:
    the plant drops the roll/pitch rate feed-forward itself (the emulator's autopilot drops it before);
    vision_timeout_s: the estimate's position timeout (the autopilot's; None: Estimate's own); estimate_wrapper:
    a callable wrapping the Estimate (an offline model's variant)."""
    check_drag(args.drag_per_s)   # bad values before the vehicle file is read
    estimate_options = {} if vision_timeout_s is None else {'vision_timeout_s': vision_timeout_s}
    estimate = Estimate(args.estimator_lag_s, args.estimator_wander_m, args.estimator_wander_z_m,
                        args.estimator_wander_tau_s, args.seed, args.estimator_velocity_noise_mps,
                        args.estimator_velocity_wander_mps, args.estimator_velocity_wander_z_mps,
                        args.estimator_velocity_wander_tau_s, smoothing_s=args.estimator_wander_smoothing_s,
                        **estimate_options)
    if estimate_wrapper is not None:
        estimate = estimate_wrapper(estimate)
    vehicle, drag = with_linear_drag(emulated_vehicle(parameter_file('--vehicle', args.vehicle),
                                                      rate_loop=args.rate_loop), args.drag_per_s)
    sim = Simulator(vehicle, physics_rate_hz=args.physics_rate_hz, initial_position=args.initial_position,
                    initial_yaw=args.initial_yaw, setpoint_timeout_s=1e6, disturbances=drag)
    tau_s = default_tau_s(vehicle) if args.attitude_tau_s is None else args.attitude_tau_s
    return AutopilotPlant(sim, AttitudeResponse(tau_s, sim.state.quaternion, args.attitude_dead_time_s), estimate,
                          rp_rates_fed=rp_rates_fed, vision=vision, estimate_now=estimate_now)


class VisionFeed:
    """Motion-capture poses into the autopilot's estimator: the truth measured by quad_sim.mocap's stand-in (its
    rate, noise and latency: the pose's age at the autopilot), each delivered pose fused at the instant the
    autopilot's EKF takes for it (external_vision.VisionClock, with the delay parameter delay_ms)."""

    def __init__(self, flavour: str, config: MocapConfig, delay_ms: float, seed: int = 0):
        self.mocap = MotionCapture(config, seed)
        self.clock = VisionClock(flavour)
        self.delay_ms = float(delay_ms)

    def poses(self, time_ns: int, truth: State):
        """(position ENU, fusion time s) of each pose delivered by time_ns."""
        for frame in self.mocap.offer(time_ns, truth.position, truth.quaternion):
            fusion_us = self.clock.fusion_us(frame.stamp_ns // 1000, time_ns // 1000, self.delay_ms)
            yield frame.position, fusion_us * 1e-6


class AutopilotPlant:
    def __init__(self, sim: Simulator, response: AttitudeResponse, estimate=None, rp_rates_fed: bool = True,
                 vision: VisionFeed | None = None, estimate_now: bool = True):
        """estimate: an estimator.Estimate (None: the telemetry reports sim.odometry_state()). vision: the
        estimate's position fused from motion capture on every axis in advance (external vision as the position
        source). estimate_now: the estimate steps at the simulator's time here (the offline harness observes the
        plant before its first period); False: the truth is observed until the first step_estimate (the
        emulator's first loop tick)."""
        self.sim = sim
        self.response = response
        self.estimate = estimate
        self.rp_rates_fed = rp_rates_fed
        self.vision = vision
        self.target = None
        self.estimated = None
        if estimate_now:
            self._step_estimate()
        elif estimate is not None:
            self.estimated = sim.state

    @property
    def state(self) -> State:
        return self.sim.state

    def observed(self) -> State:
        return self.sim.odometry_state() if self.estimated is None else self.estimated

    def command(self, setpoint: AttitudeSetpoint):
        rates = setpoint.body_rates
        if rates is not None and not self.rp_rates_fed:
            rates = np.array([0.0, 0.0, rates[2]])
        self.target = AttitudeSetpoint(quaternion=setpoint.quaternion,
                                       specific_force_mps2=setpoint.specific_force_mps2, body_rates=rates)

    def rest(self, quaternion):
        """No target (the autopilot disarmed): the response at rest at quaternion, where the next target starts
        it from."""
        self.target = None
        self.response.reset(quaternion)

    def respond(self, dt_s: float):
        """The target through the attitude response over dt_s, into the simulator's onboard loop."""
        if self.target is not None:
            q, w = self.response.step(self.target.quaternion, dt_s, self.target.body_rates)
            self.sim.set_setpoint(AttitudeSetpoint(quaternion=q, specific_force_mps2=self.target.specific_force_mps2,
                                                   body_rates=w))

    def advance_steps(self, steps: int):
        """Physics only: steps of the simulator (raising quad_sim.simulator.SimulationStopped)."""
        self.sim.advance_steps(steps)

    def advance(self, dt_s: float):
        self.respond(dt_s)
        self.advance_steps(self.sim.steps_in(dt_s))
        self._step_estimate()

    def fuse_vision(self, position_enu, fusion_time_s: float):
        """An external-vision pose (world ENU) into the estimate, as measured at fusion_time_s (its clock)."""
        self.estimate.fuse_vision(position_enu, fusion_time_s)

    def step_estimate(self, now_s: float, vision_axes) -> State:
        """The estimate at now_s of the truth now (times increasing), its position from the fused poses on
        vision_axes (world ENU): what observed() reports from now."""
        self.estimated = self.estimate.step(now_s, self.sim.state, vision_axes)
        return self.estimated

    def _step_estimate(self):
        if self.estimate is None:
            return
        if self.vision is not None:
            for position, fusion_s in self.vision.poses(self.sim.time_ns, self.sim.state):
                self.fuse_vision(position, fusion_s)
        self.step_estimate(self.sim.time_ns * 1e-9, (self.vision is not None,) * 3)
