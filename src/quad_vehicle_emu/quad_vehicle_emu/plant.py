"""The emulated autopilot's vehicle side, composed once (no MAVLink, no clock): quad_sim's Simulator flying
the vehicle as the emulator flies it (`attitude.emulated_vehicle`, linear air drag), the autopilot's attitude
response in front of it (`attitude.AttitudeResponse`: first order behind a dead time), roll/pitch rate
feed-forward dropped where the autopilot drops it (PX4's mavlink_receiver keeps only the yaw rate of a
SET_ATTITUDE_TARGET that carries an attitude), and the estimate its telemetry reports (`estimator.Estimate`),
fused from external-vision poses as the autopilot fuses them. The offline harness flies this class period by
period on the simulator's time, the emulator's real-time loop (mavlink_vehicle) tick by tick on its own clock
with the poses it receives.

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

import numpy as np

from quad_common.types import AttitudeSetpoint, State
from quad_sim.mocap import MocapConfig, MotionCapture
from quad_sim.simulator import Simulator
from quad_vehicle_emu.attitude import AttitudeResponse
from quad_vehicle_emu.external_vision import VisionClock

PHYSICS_RATE_HZ = 500.0   # the emulator's physics rate (mavlink_vehicle --physics-rate-hz): its onboard loop's


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
