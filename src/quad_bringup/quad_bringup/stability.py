"""Is a control profile stable on an autopilot's attitude response? The offline check of a profile the bridge flies.

The plant is the emulator's (quad_vehicle_emu.mavlink_vehicle, its main loop step for step): quad_sim's Simulator
with the autopilot's quaternion attitude loop (quad_vehicle_emu.attitude.emulated_vehicle), behind
quad_vehicle_emu.attitude.AttitudeResponse with tau = lag - the loop's own lag (tau_for_lag_s: the total roll/pitch
lag is the requested one), its telemetry read through quad_vehicle_emu.attitude.DelayLine (latency) at the bridge's
50 Hz and released in ArduPilot's bursts (up to 40 ms apart, as the emulator does), and a hover-thrust error
(delivered / commanded specific force = 1 + thrust_error: the bridge's hover_throttle vs the vehicle's true one).
The controller is quad_control's PositionController, the one position_controller's ControlLoop runs, at its rate,
holding a point from a start offset. No ROS, no sockets: the graph version is test/test_bridge_real_profile.py.

Measured on ArduCopter (issue 13): roll/pitch lag 0.17-0.21 s, ~50 ms of telemetry. A profile is offered
only with margin: it settles (no sustained oscillation) at MARGIN_LAG x the lag and MARGIN_LATENCY x the latency.
"""

from dataclasses import dataclass

import numpy as np

from quad_common import rotations
from quad_common.types import AttitudeSetpoint, Reference
from quad_common.vehicle import load_vehicle
from quad_control.loop import RATE_HZ
from quad_control.position import Limits, PositionController, PositionGains
from quad_sim.simulator import SimulationStopped, Simulator
from quad_vehicle_emu.attitude import AttitudeResponse, DelayLine, emulated_vehicle, own_lag_s, tau_for_lag_s
from quad_vehicle_emu.mavlink_vehicle import DEFAULT_BURST_S

MEASURED_LAG_S = (0.17, 0.21)    # ArduCopter SITL roll/pitch under pd/pid (issue 13)
MEASURED_LATENCY_S = 0.05        # its telemetry
MARGIN_LAG = 1.5
MARGIN_LATENCY = 2.0
SETTLED_TILT_DEG = 2.0           # largest tilt over the last quarter of a settled hold
SETTLED_OSCILLATION_DEG = 0.5    # tilt standard deviation over the last quarter of a settled hold
SETTLED_OSCILLATION_M = 0.005    # position standard deviation over the last quarter of a settled hold
TELEMETRY_RATE_HZ = 50.0         # mavlink_bridge's telemetry_rate_hz: the odometry stream it requests
BURST_S = DEFAULT_BURST_S['ardupilot']   # ArduPilot SITL's telemetry arrived 0.5-65 ms apart (issue 13)
HOLD_ALTITUDE_M = 20.0           # room for a flip to show as a flip, not as ground contact


@dataclass
class Hold:
    """One hold: the final offset (mean position over the last quarter - target, m), the largest tilt over the
    last quarter and over the whole hold (deg), the oscillation (standard deviation of roll and pitch over the
    last quarter, deg: a sustained oscillation keeps it up, a settled hover brings it to ~0; the vertical loop,
    which tilt does not show, in oscillation_m: the position's standard deviation), its frequency (Hz, zero
    crossings of x about its mean over the last quarter) and why the simulator stopped, if it did."""
    lag_s: float
    latency_s: float
    thrust_error: float
    offset_m: float
    late_tilt_deg: float
    peak_tilt_deg: float
    oscillation_deg: float
    oscillation_m: float
    oscillation_hz: float
    stopped: str | None = None

    @property
    def settled(self) -> bool:
        return (self.stopped is None and self.late_tilt_deg < SETTLED_TILT_DEG
                and self.oscillation_deg < SETTLED_OSCILLATION_DEG and self.oscillation_m < SETTLED_OSCILLATION_M)

    def describe(self) -> str:
        head = (f'attitude lag {self.lag_s:.3f} s, telemetry latency {self.latency_s:.3f} s, thrust error '
                f'{100 * self.thrust_error:+.1f} %: ')
        if self.stopped:
            return head + f'lost ({self.stopped}), peak tilt {self.peak_tilt_deg:.1f} deg'
        verdict = 'settled' if self.settled else 'NOT settled'
        return head + (f'offset {100 * self.offset_m:.2f} cm, tilt over the last quarter {self.late_tilt_deg:.2f} deg '
                       f'(peak {self.peak_tilt_deg:.1f}), oscillation {self.oscillation_deg:.2f} deg / '
                       f'{100 * self.oscillation_m:.2f} cm rms at {self.oscillation_hz:.2f} Hz: {verdict}')


def hold_on_autopilot(vehicle_path, controller: str, gains: PositionGains, lag_s: float, latency_s: float,
                      thrust_error: float = 0.0, start_offset_m=(0.5, 0.0, 0.3), duration_s: float = 20.0,
                      rate_hz: float = RATE_HZ, physics_rate_hz: float = 500.0,
                      telemetry_rate_hz: float = TELEMETRY_RATE_HZ, burst_s: float = BURST_S, seed: int = 0,
                      initial_yaw_rad: float = 0.0) -> Hold:
    """The controller holds a point from start_offset_m behind the emulator's attitude response (lag_s) and
    telemetry (latency_s) on vehicle_path's plant with thrust_error, facing initial_yaw_rad (the point's yaw is
    0). Each period, as mavlink_vehicle's loop: the controller sees the newest telemetry at least latency_s old,
    its attitude goes through the shaping, the physics advances one period, the new state enters the telemetry
    line (at telemetry_rate_hz: what the bridge asks the vehicle for). Telemetry leaves in bursts up to burst_s
    apart (uniform, seeded), as the emulated ArduPilot sends it: between bursts the controller sees the last one
    released."""
    nominal = load_vehicle(vehicle_path)    # what the controller is configured with
    plant = emulated_vehicle(vehicle_path, {'thrust_error': thrust_error} if thrust_error else None)
    target = np.array([0.0, 0.0, HOLD_ALTITUDE_M])
    sim = Simulator(plant, physics_rate_hz=physics_rate_hz, initial_position=target + np.asarray(start_offset_m,
                                                                                                 dtype=float),
                    initial_yaw=initial_yaw_rad, setpoint_timeout_s=1e6)
    shaper = AttitudeResponse(tau_for_lag_s(plant, lag_s), sim.state.quaternion)
    telemetry = DelayLine(latency_s)
    control = PositionController(controller, gains, nominal, Limits.of(nominal))
    ref = Reference(position=target, velocity=np.zeros(3), acceleration=np.zeros(3), jerk=np.zeros(3), yaw=0.0,
                    yaw_rate=0.0)
    period_s = 1.0 / rate_hz
    steps = sim.steps_in(round(period_s * physics_rate_hz) / physics_rate_hz)
    telemetry.push(-latency_s, sim.odometry_state())   # at rest there since before the first read
    every = max(int(round(rate_hz / telemetry_rate_hz)), 1)
    positions, euler = [], []
    stopped = None
    rng = np.random.default_rng(seed)
    next_burst_s = 0.0
    for k in range(int(round(duration_s * rate_hz))):
        t_s = k * period_s
        if t_s >= next_burst_s:
            _, seen = telemetry.read(t_s)
            next_burst_s = t_s + rng.uniform(0.0, burst_s)
        setpoint, _ = control.update(seen, ref, period_s if k else 0.0)
        q, w = shaper.step(setpoint.quaternion, period_s, setpoint.body_rates)
        sim.set_setpoint(AttitudeSetpoint(quaternion=q, specific_force_mps2=setpoint.specific_force_mps2,
                                          body_rates=w))
        try:
            sim.advance_steps(steps)
        except SimulationStopped as exc:
            stopped = str(exc)
            break
        if (k + 1) % every == 0:
            telemetry.push(t_s + period_s, sim.odometry_state())
        positions.append(sim.state.position)
        euler.append(rotations.to_euler(sim.state.quaternion)[:2])
        if sim.landed or sim.state.position[2] < 1.0:
            stopped = f'fell to the ground at t = {t_s:.2f} s'
            break
    tilt = np.degrees(np.hypot(*np.array(euler).T)) if euler else np.zeros(1)
    if stopped:
        return Hold(lag_s, latency_s, thrust_error, float('inf'), float(tilt[-1]), float(np.max(tilt)), float('inf'),
                    float('inf'), 0.0, stopped)
    last = len(positions) * 3 // 4
    late_pos, late_euler = np.array(positions[last:]), np.degrees(np.array(euler[last:]))
    error = late_pos[:, 0] - target[0]
    crossings = np.count_nonzero(np.diff(np.sign(error - error.mean())) != 0)
    def rms(x):
        return float(np.sqrt(np.mean(np.sum((x - x.mean(axis=0)) ** 2, axis=1))))

    return Hold(lag_s, latency_s, thrust_error, float(np.linalg.norm(late_pos.mean(axis=0) - target)),
                float(np.max(tilt[last:])), float(np.max(tilt)), rms(late_euler), rms(late_pos),
                float(crossings / 2 / (len(error) * period_s)), None)


def margin_hold(vehicle_path, controller: str, gains: PositionGains, lag_s: float,
                latency_s: float = MEASURED_LATENCY_S, thrust_error: float = 0.0, **kwargs) -> Hold:
    """The hold at MARGIN_LAG x lag_s (at least the vehicle's own loop's lag: shaping cannot make it faster) and
    MARGIN_LATENCY x latency_s: a profile is offered when it settles there."""
    lag_s = max(MARGIN_LAG * lag_s, own_lag_s(emulated_vehicle(vehicle_path)))
    return hold_on_autopilot(vehicle_path, controller, gains, lag_s, MARGIN_LATENCY * latency_s, thrust_error,
                             **kwargs)
