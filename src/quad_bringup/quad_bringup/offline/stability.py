"""Is a control profile stable on an autopilot's attitude response? The offline check of a profile the bridge flies.

The plant is the emulator's (quad_vehicle_emu.plant.AutopilotPlant): quad_sim's Simulator with the autopilot's
quaternion attitude loop (quad_vehicle_emu.attitude.emulated_vehicle), behind quad_vehicle_emu.attitude.AttitudeResponse
with tau = lag - the loop's own lag (tau_for_lag_s: the total roll/pitch lag is the requested one), its telemetry
through the harness's DelayLine (latency) at the bridge's 50 Hz and released in ArduPilot's bursts (up to 40 ms
apart, as the emulator does), and a hover-thrust error (delivered / commanded specific force = 1 + thrust_error: the
bridge's hover_throttle vs the vehicle's true one). The controller flies through the flight harness
(quad_bringup.offline.harness: position_controller's ControlLoop at its rate), holding a point from a start offset. No
ROS, no sockets: the graph version is test/bridge/test_bridge_real_profile.py.

Measured on ArduCopter SITL: roll/pitch lag 0.17-0.21 s, ~50 ms of telemetry. A profile is offered
only with margin: it settles (no sustained oscillation) at MARGIN_LAG x the lag and MARGIN_LATENCY x the latency.

`quadflight identify` checks the response it measured instead (hold_on_autopilot's `response`): the FOPDT fit's
tau y' = u(t - d) - y per roll/pitch axis as the plant's own attitude loop (quad_sim's `lag` loop with
time_constant_s = tau, tracked with the target's rate fed forward: no further delay) behind a dead time d on the
commanded attitude, both x MARGIN_LAG, with the telemetry the bag shows (Telemetry: its latency, rate and bursts).
The emulator's structure (a 1 / 6.5 s angle-P loop plus shaping) lags a response of the same mean delay by ~16 deg
more at the position loop's crossover (6 rad/s at 0.27 s), so it refused what rotorpy's PD attitude loop (one
dominant pole) flies with little overshoot at 1.5x its lag.
"""

import math
from dataclasses import dataclass

import numpy as np

from quad_bringup.limits import (  # noqa: F401  (the margin's numbers: in limits, which help pages read)
    MARGIN_LAG,
    MARGIN_LATENCY,
    MEASURED_LAG_S,
    MEASURED_LATENCY_S,
)
from quad_bringup.offline.harness import DelayLine, fly
from quad_common import rotations
from quad_common.types import Reference
from quad_common.vehicle import load_vehicle
from quad_control.loop import RATE_HZ, ControlLoop
from quad_control.plugins import make_controller
from quad_control.position import Limits, PositionGains
from quad_sim.simulator import Simulator
from quad_vehicle_emu.attitude import AttitudeResponse, emulated_vehicle, own_lag_s, tau_for_lag_s
from quad_vehicle_emu.mavlink_vehicle import DEFAULT_BURST_S
from quad_vehicle_emu.plant import PHYSICS_RATE_HZ, AutopilotPlant

SETTLED_TILT_DEG = 2.0           # largest tilt over the last quarter of a settled hold
SETTLED_OSCILLATION_DEG = 0.5    # tilt standard deviation over the last quarter of a settled hold
SETTLED_OSCILLATION_M = 0.005    # position standard deviation over the last quarter of a settled hold
TELEMETRY_RATE_HZ = 50.0         # mavlink_bridge's telemetry_rate_hz: the odometry stream it requests
BURST_S = DEFAULT_BURST_S['ardupilot']   # ArduPilot SITL's telemetry arrived 0.5-65 ms apart
HOLD_ALTITUDE_M = 20.0           # room for a flip to show as a flip, not as ground contact
WALL_CLOCK_NS = 10**18           # stamps past 2001: a wall clock, not a simulator's time from 0 (as identify)


@dataclass
class Telemetry:
    """The odometry the controller saw in a flight (Telemetry.of_flight): its latency (s), rate (Hz), the longest
    gap between its arrivals beyond one period (burst_s, 0: regular) and where each came from."""
    latency_s: float
    rate_hz: float
    burst_s: float
    source: str

    def describe(self) -> str:
        return (f'telemetry latency {self.latency_s:.3f} s, {self.rate_hz:.0f} Hz, bursts up to {self.burst_s:.3f} s '
                f'({self.source})')

    @classmethod
    def of_flight(cls, flight, latency_s: float | None = None) -> 'Telemetry':
        """From a bag's odometry: rate = 1 / median stamp interval. A simulator's bag (sim time: stamped when
        computed, read in lockstep): latency 0, no bursts. A vehicle's bag (wall-clock stamps): latency = median
        (record time - stamp), but at least MEASURED_LATENCY_S (what the vehicle's own estimator adds before its
        stamp is not in the bag); bursts = 99th percentile of the record-time gaps - the period. latency_s
        (--latency-s) replaces the bag's latency."""
        stamps = np.asarray(flight.odom_t, dtype=float)
        period_s = float(np.median(np.diff(stamps))) if len(stamps) > 1 else 0.01
        rate_hz = 1.0 / period_s
        record = np.asarray(flight.odom_record_ns, dtype=np.int64)
        simulator = len(flight.clock_stamps_ns) > 0 or (len(stamps) and stamps[0] * 1e9 < WALL_CLOCK_NS)
        if simulator or len(record) != len(stamps) or len(record) < 2:
            measured, burst, source = 0.0, 0.0, 'a simulator\'s bag, lockstep odometry'
        else:
            measured = max(float(np.median(record * 1e-9 - stamps)), MEASURED_LATENCY_S)
            burst = max(float(np.percentile(np.diff(np.sort(record)) * 1e-9, 99)) - period_s, 0.0)
            source = f'a vehicle\'s bag: record - stamp times, latency at least {MEASURED_LATENCY_S} s'
        if latency_s is not None:
            source += f'; latency {latency_s:.3f} s as given (the bag: {measured:.3f} s)'
            measured = float(latency_s)
        return cls(measured, rate_hz, burst, source)


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


class HoldPoint:
    """A plan that is one point: ControlLoop tracks it as it tracks any plan (duration 0: after its end, the point)."""
    duration_s = 0.0

    def __init__(self, reference: Reference):
        self.point = reference

    def reference(self, t_s: float) -> Reference:
        return self.point


def hold_on_autopilot(vehicle_path, controller: str, gains: PositionGains, lag_s: float, latency_s: float,
                      thrust_error: float = 0.0, start_offset_m=(0.5, 0.0, 0.3), duration_s: float = 20.0,
                      rate_hz: float = RATE_HZ, physics_rate_hz: float = PHYSICS_RATE_HZ,
                      telemetry_rate_hz: float = TELEMETRY_RATE_HZ, burst_s: float = BURST_S, seed: int = 0,
                      initial_yaw_rad: float = 0.0, response: tuple | None = None, rate_loop: str = 'default',
                      dead_time_s: float = 0.0) -> Hold:
    """The controller holds a point from start_offset_m behind the emulator's attitude response (lag_s) and
    telemetry (latency_s) on vehicle_path's plant with thrust_error, facing initial_yaw_rad (the point's yaw is
    0), through the flight harness (quad_bringup.offline.harness: position_controller's ControlLoop; the point is its
    plan, no start-step guard) on the emulated autopilot's plant (quad_vehicle_emu.plant). The telemetry samples the
    state at telemetry_rate_hz (what the bridge asks the vehicle for), latency_s late, released in bursts up to
    burst_s apart (uniform, seeded), as the emulated ArduPilot sends it. response = (tau_s, dead_time_s): the
    plant's attitude response is that first order plus dead time (the module) instead of the emulator's; lag_s is
    then tau_s + dead_time_s (reported only). Otherwise the emulator's plant with its --rate-loop (rate_loop) and
    --attitude-dead-time-s (dead_time_s, part of lag_s)."""
    nominal = load_vehicle(vehicle_path)    # what the controller is configured with
    extra = {'thrust_error': thrust_error} if thrust_error else {}
    period_s = 1.0 / rate_hz
    if response is not None:
        tau_s, dead_time_s = (float(x) for x in response)
        plant = load_vehicle(vehicle_path, plant={**extra, 'attitude_loop': {'type': 'lag', 'time_constant_s': tau_s}})
        lag_s, shaping_tau_s = tau_s + dead_time_s, 0.0
        dead_time_s = max(math.ceil(dead_time_s / period_s - 0.5 - 1e-9), 0) * period_s   # nearest period, a half down
    else:
        plant = emulated_vehicle(vehicle_path, extra or None, rate_loop=rate_loop)
        shaping_tau_s = None
    target = np.array([0.0, 0.0, HOLD_ALTITUDE_M])
    sim = Simulator(plant, physics_rate_hz=physics_rate_hz, initial_position=target + np.asarray(start_offset_m,
                                                                                                 dtype=float),
                    initial_yaw=initial_yaw_rad, setpoint_timeout_s=1e6)
    if shaping_tau_s is None:
        shaping_tau_s = tau_for_lag_s(plant, lag_s - dead_time_s)
    vehicle = AutopilotPlant(sim, AttitudeResponse(shaping_tau_s, sim.state.quaternion, dead_time_s))
    loop = ControlLoop(make_controller(controller, gains, nominal, Limits.of(nominal), rate_hz), rate_hz)
    loop.set_trajectory(0, HoldPoint(Reference(position=target, yaw=0.0)))
    telemetry = DelayLine(latency_s, max(int(round(rate_hz / telemetry_rate_hz)), 1), burst_s, seed,
                          initial=sim.odometry_state())

    def fell(t_ns, truth):
        if sim.landed or truth.position[2] < 1.0:
            return f'fell to the ground at t = {t_ns * 1e-9 - period_s:.2f} s'
        return None

    flown = fly(loop, vehicle, telemetry, int(round(duration_s * rate_hz)), fault=fell)
    after = flown.track()[1][1:]     # the state after each period
    positions = [s.position for s in after]
    euler = [rotations.to_euler(s.quaternion)[:2] for s in after]
    return hold_of(lag_s, latency_s, thrust_error, positions, euler, target, period_s, flown.stopped)


def hold_of(lag_s, latency_s, thrust_error, positions, euler, target, period_s, stopped=None) -> Hold:
    """The Hold of a flown hold: positions (n, 3) and (roll, pitch) (n, 2, rad) every period_s about target (also
    what the tests score another simulator's hold with)."""
    tilt = np.degrees(np.hypot(*np.array(euler).T)) if len(euler) else np.zeros(1)
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


def margin_response(result: dict) -> tuple[float, float]:
    """(tau_s, dead_time_s) x MARGIN_LAG of identify's slower roll/pitch fit (the larger lag)."""
    axis = max((result['roll'], result['pitch']), key=lambda a: a['lag_s'])
    return MARGIN_LAG * axis['tau_s'], MARGIN_LAG * axis['delay_s']


def margin_hold_identified(vehicle_path, controller: str, gains: PositionGains, result: dict,
                           telemetry: Telemetry, **kwargs) -> Hold:
    """The hold on the response identify measured (margin_response: MARGIN_LAG x its tau and dead time), with the
    thrust scale it found and MARGIN_LATENCY x the bag's telemetry latency at the bag's rate and bursts."""
    return hold_on_autopilot(vehicle_path, controller, gains, 0.0, MARGIN_LATENCY * telemetry.latency_s,
                             result['thrust_scale'] - 1.0, telemetry_rate_hz=telemetry.rate_hz,
                             burst_s=telemetry.burst_s, response=margin_response(result), **kwargs)
