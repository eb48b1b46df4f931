"""The emulated autopilot's vehicle side, composed once (no MAVLink, no clock): quad_sim's Simulator flying
the vehicle as the emulator flies it (`attitude.emulated_vehicle`, linear air drag), the autopilot's attitude
response in front of it (`attitude.AttitudeResponse`: first order behind a dead time), roll/pitch rate
feed-forward dropped where the autopilot drops it (PX4's mavlink_receiver keeps only the yaw rate of a
SET_ATTITUDE_TARGET that carries an attitude), and the estimate its telemetry reports (`estimator.Estimate`),
fused, with a VisionFeed, from motion-capture poses on every axis as the autopilot fuses external vision.

Each period T of the offline flight harness (quad_bringup.offline.harness):

    command(setpoint)      a new setpoint: the autopilot's target from now on
    advance(T)             the target through the response into the simulator, physics; then the poses delivered
                           by now are fused and the estimate steps
    observed()             what the vehicle's telemetry sends now (the estimate, else the odometry)
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

    def fuse(self, estimate, time_ns: int, truth: State):
        for frame in self.mocap.offer(time_ns, truth.position, truth.quaternion):
            fusion_us = self.clock.fusion_us(frame.stamp_ns // 1000, time_ns // 1000, self.delay_ms)
            estimate.fuse_vision(frame.position, fusion_us * 1e-6)


class AutopilotPlant:
    def __init__(self, sim: Simulator, response: AttitudeResponse, estimate=None, rp_rates_fed: bool = True,
                 vision: VisionFeed | None = None):
        """estimate: an estimator.Estimate (None: the telemetry reports sim.odometry_state()); it steps at the
        simulator's time here and after every advance, as the emulator steps it once per loop tick. vision: the
        estimate's position fused from motion capture on every axis (external vision as the position source)."""
        self.sim = sim
        self.response = response
        self.estimate = estimate
        self.rp_rates_fed = rp_rates_fed
        self.vision = vision
        self.target = None
        self.estimated = None
        self._step_estimate()

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

    def advance(self, dt_s: float):
        if self.target is not None:
            q, w = self.response.step(self.target.quaternion, dt_s, self.target.body_rates)
            self.sim.set_setpoint(AttitudeSetpoint(quaternion=q, specific_force_mps2=self.target.specific_force_mps2,
                                                   body_rates=w))
        self.sim.advance_steps(self.sim.steps_in(dt_s))
        self._step_estimate()

    def _step_estimate(self):
        if self.estimate is None:
            return
        if self.vision is not None:
            self.vision.fuse(self.estimate, self.sim.time_ns, self.sim.state)
        self.estimated = self.estimate.step(self.sim.time_ns * 1e-9, self.sim.state, (self.vision is not None,) * 3)
