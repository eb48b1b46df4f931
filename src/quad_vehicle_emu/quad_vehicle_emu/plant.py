"""The emulated autopilot's vehicle side, composed once (no MAVLink, no clock): quad_sim's Simulator flying
the vehicle as the emulator flies it (`attitude.emulated_vehicle`, linear air drag), the autopilot's attitude
response in front of it (`attitude.AttitudeResponse`: first order behind a dead time), roll/pitch rate
feed-forward dropped where the autopilot drops it (PX4's mavlink_receiver keeps only the yaw rate of a
SET_ATTITUDE_TARGET that carries an attitude), and the estimate its telemetry reports (`estimator.Estimate`).

Each period T of the offline flight harness (quad_bringup.harness):

    command(setpoint)      a new setpoint: the autopilot's target from now on
    advance(T)             the target through the response into the simulator, physics; then the estimate steps
    observed()             what the vehicle's telemetry sends now (the estimate, else the odometry)
"""

import numpy as np

from quad_common.types import AttitudeSetpoint, State
from quad_sim.simulator import Simulator
from quad_vehicle_emu.attitude import AttitudeResponse

PHYSICS_RATE_HZ = 500.0   # the emulator's physics rate (mavlink_vehicle --physics-rate-hz): its onboard loop's


class AutopilotPlant:
    def __init__(self, sim: Simulator, response: AttitudeResponse, estimate=None, rp_rates_fed: bool = True):
        """estimate: an estimator.Estimate (None: the telemetry reports sim.odometry_state()); it steps at the
        simulator's time here and after every advance, as the emulator steps it once per loop tick."""
        self.sim = sim
        self.response = response
        self.estimate = estimate
        self.rp_rates_fed = rp_rates_fed
        self.target = None
        self.estimated = None if estimate is None else estimate.step(sim.time_ns * 1e-9, sim.state)

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
        if self.estimate is not None:
            self.estimated = self.estimate.step(self.sim.time_ns * 1e-9, self.sim.state)
