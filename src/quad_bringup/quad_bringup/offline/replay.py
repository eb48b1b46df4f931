"""A flight's digital twin (no rclpy): the bag's plan flown again in quad_sim on a vehicle model, closed loop
with the position controller and gains, and the bag's setpoints fed open loop.

Closed loop: through the flight harness (quad_bringup.offline.harness: position_controller's ControlLoop at RATE_HZ with
the controller and gains) it tracks the recorded plan (the bag's `trajectory`) on Simulator(vehicle) from the
flight's position and yaw at the plan's start, each tick seeing the simulator's odometry as old as the flight's
controller saw the vehicle's (telemetry_of: the mean age the controller reported, else the bag's median record -
stamp age plus half its odometry period, the mean wait for the next sample; harness.FixedAge: the state that long
ago, interpolated between ticks, so a 30 ms age is not rounded to a 10 ms tick; a simulator's lockstep bag: fresh
every tick, as the offline loop quad_bringup.offline.closed_loop does). Through a vehicle's link the
controller at t flies the state of t - age: the vehicle runs ahead of the plan by about that age, so a twin
with fresh odometry is no twin. Both with the model's aerodynamics (DRAG: the
drag identify measured; a vehicle file's own coefficients act too). Open loop: the recorded cmd/attitude_thrust
(held from stamp to stamp) drives Simulator(vehicle) from the same start: errors of the model integrate, so it
is scored over OPEN_LOOP_S only.

Scored on the flight's odometry stamps inside the plan (start to end): the flight's tracking error |p - plan|,
the twin's |p_twin - plan| (RMSE of each: the goal is the twin's within RMSE_GOAL of the flight's), and the
trace error |p_twin - p_flight| (closed and open loop).
"""

import numpy as np

from quad_bringup.analysis.metrics import planned_position
from quad_bringup.offline.harness import FixedAge, SimulatorPlant, fly
from quad_common import rotations
from quad_common.types import AttitudeSetpoint
from quad_common.vehicle import load_vehicle
from quad_control.loop import RATE_HZ, ControlLoop
from quad_control.plugins import make_controller
from quad_control.position import Limits, PositionGains
from quad_sim.disturbances import profile_from_dict
from quad_sim.simulator import SimulationStopped, Simulator

DRAG = profile_from_dict({'body_drag': True, 'rotor_drag': True}, 'replay')   # the model's aerodynamics: what
#                                          identify measured (0 where it saw none)
OPEN_LOOP_S = 2.0        # the open-loop trace is scored over the plan's first seconds (it drifts)
RMSE_GOAL = 0.2          # the twin's closed-loop RMSE within 20 % of the flight's
REPORT_PERIOD_S = 1.0    # position_controller's diagnostics period: the report after the plan's end covers its
#                          last ticks


def _rmse(x) -> float:
    return float(np.sqrt(np.mean(np.sum(np.square(x), axis=-1)))) if len(x) else float('nan')


def telemetry_of(flight, window_s=None) -> tuple[float, float, str]:
    """(age_s, period_s, source) of the odometry the flight's controller saw. Where the controller reported it (its
    diagnostics' contract.CONTROLLER_ODOM_AGE_MS over window_s, bag time: tick - odometry stamp, so the link, the
    wait for the next sample and the phase of its timer against the telemetry are the flight's own) that mean age
    and period 0; else a vehicle's bag (wall-clock stamps) the median record - stamp time (the recorder's own
    delays included) and the median stamp interval; a simulator's bag (sim time, lockstep) (0, 0): fresh
    odometry every tick."""
    from quad_bringup.offline.stability import WALL_CLOCK_NS
    stamps = np.asarray(flight.odom_t, dtype=float)
    record = np.asarray(flight.odom_record_ns, dtype=np.int64)
    simulator = len(flight.clock_stamps_ns) > 0 or (len(stamps) and stamps[0] * 1e9 < WALL_CLOCK_NS)
    if simulator or len(record) != len(stamps) or len(stamps) < 2:
        return 0.0, 0.0, 'a simulator\'s lockstep bag: fresh'
    reported = [ms for record_ns, ms in flight.controller_odom_age
                if window_s is None or window_s[0] <= record_ns * 1e-9 <= window_s[1] + REPORT_PERIOD_S]
    if reported:
        return max(float(np.mean(reported)) * 1e-3, 0.0), 0.0, 'as the controller reported it'
    return (max(float(np.median(record * 1e-9 - stamps)), 0.0), float(np.median(np.diff(stamps))),
            'as the bag shows (record - stamp)')


def _simulator(vehicle, start_p, start_yaw) -> Simulator:
    return Simulator(vehicle, initial_position=start_p, initial_yaw=start_yaw, setpoint_timeout_s=1e6,
                     disturbances=DRAG)


def _open_loop(vehicle, start_p, start_yaw, t0_s, end_s, setpoint_at):
    """(times, positions, stopped) of Simulator(vehicle) from rest at start_p / start_yaw fed setpoint_at(t_s)
    each 1 / RATE_HZ from t0_s to end_s (no controller: the recorded commands)."""
    sim = _simulator(vehicle, start_p, start_yaw)
    period_s = 1.0 / RATE_HZ
    times, positions = [t0_s], [sim.state.position]
    stopped = None
    for k in range(int(round((end_s - t0_s) * RATE_HZ))):
        t_s = t0_s + k * period_s
        sim.set_setpoint(setpoint_at(t_s))
        try:
            sim.advance(period_s)
        except SimulationStopped as exc:
            stopped = str(exc)
            break
        times.append(t_s + period_s)
        positions.append(sim.state.position)
    return np.array(times), np.array(positions), stopped


def replay(flight, vehicle_path, controller: str, gains: PositionGains, telemetry: tuple | None = None) -> dict:
    """The twin of `flight` (quad_bringup.analysis.report.Flight with a plan and commands) on vehicle_path's model.
    telemetry: (age_s, period_s) in place of the bag's (telemetry_of); (0, 0) sees fresh odometry every tick."""
    if flight.trajectory is None:
        raise ValueError('the bag has no plan (topic trajectory): nothing to fly again')
    if len(flight.cmd_t) == 0:
        raise ValueError('the bag has no commanded attitude (topic cmd/attitude_thrust): no open loop to feed')
    vehicle = load_vehicle(vehicle_path)
    nominal = load_vehicle(vehicle_path)
    traj, t0_s = flight.trajectory, float(flight.traj_start_s)
    end_s = min(t0_s + traj.duration_s, float(flight.odom_t[-1]))
    i0 = int(np.searchsorted(flight.odom_t, t0_s))
    start_p, start_yaw = flight.position[i0], float(flight.euler[i0, 2])
    age_s, odom_period_s, source = ((*telemetry, 'given') if telemetry is not None
                                    else telemetry_of(flight, (t0_s, end_s)))
    delay_s = age_s + 0.5 * odom_period_s   # a sample arrives age_s late and is flown until the next: its mean age
    loop = ControlLoop(make_controller(controller, gains, nominal, Limits.of(nominal), RATE_HZ), RATE_HZ)
    t0_ns = round(t0_s * 1e9)
    loop.set_trajectory(t0_ns, traj)
    closed = fly(loop, SimulatorPlant(_simulator(vehicle, start_p, start_yaw)), FixedAge(delay_s),
                 int(round((end_s - t0_s) * RATE_HZ)), start_ns=t0_ns)
    t_c, states = closed.track()
    p_c = np.array([s.position for s in states])
    stopped_c = closed.stopped
    cmd_q = rotations.from_euler(flight.cmd_euler[:, 0], flight.cmd_euler[:, 1], flight.cmd_euler[:, 2])

    def recorded(t_s):
        j = max(int(np.searchsorted(flight.cmd_t, t_s + 1e-9, side='right')) - 1, 0)
        return AttitudeSetpoint(quaternion=np.asarray(cmd_q[j]),
                                specific_force_mps2=float(flight.cmd_specific_force[j]))

    t_o, p_o, stopped_o = _open_loop(vehicle, start_p, start_yaw, t0_s, min(end_s, t0_s + OPEN_LOOP_S), recorded)
    inside = (flight.odom_t >= t0_s) & (flight.odom_t <= min(end_s, t_c[-1]))
    t = flight.odom_t[inside]
    plan = planned_position(flight, t)
    flown = flight.position[inside]
    twin = np.stack([np.interp(t, t_c, p_c[:, i]) for i in range(3)], axis=1)
    early = t <= t_o[-1]
    open_twin = np.stack([np.interp(t[early], t_o, p_o[:, i]) for i in range(3)], axis=1)
    flight_rmse, twin_rmse = _rmse(flown - plan), _rmse(twin - plan)
    return {'t_s': t, 'flight_error_m': np.linalg.norm(flown - plan, axis=1),
            'twin_error_m': np.linalg.norm(twin - plan, axis=1),
            'trace_error_m': np.linalg.norm(twin - flown, axis=1),
            'open_trace_error_m': np.linalg.norm(open_twin - flown[early], axis=1),
            'flight_rmse_m': flight_rmse, 'twin_rmse_m': twin_rmse,
            'rmse_ratio': twin_rmse / flight_rmse if flight_rmse > 0 else float('inf'),
            'trace_rmse_m': _rmse(twin - flown), 'open_trace_rmse_m': _rmse(open_twin - flown[early]),
            'open_loop_s': float(t_o[-1] - t0_s), 'stopped': stopped_c or stopped_o,
            'telemetry_age_s': age_s, 'telemetry_period_s': odom_period_s, 'telemetry_source': source}


def write_figure(result: dict, path, title: str):
    """Position error over time: the flight's and the twin's tracking error, the trace errors."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    t = result['t_s'] - result['t_s'][0]
    fig, ax = plt.subplots(figsize=(8, 4))
    ax.plot(t, 100 * result['flight_error_m'], label=f'flight |p - plan| (RMSE {100 * result["flight_rmse_m"]:.2f} cm)')
    ax.plot(t, 100 * result['twin_error_m'], label=f'twin, closed loop (RMSE {100 * result["twin_rmse_m"]:.2f} cm)')
    ax.plot(t, 100 * result['trace_error_m'], '--',
            label=f'|twin - flight| (RMSE {100 * result["trace_rmse_m"]:.2f} cm)')
    n = len(result['open_trace_error_m'])
    ax.plot(t[:n], 100 * result['open_trace_error_m'], ':',
            label=f'|open loop - flight| (RMSE {100 * result["open_trace_rmse_m"]:.2f} cm, first {OPEN_LOOP_S:g} s)')
    ax.set_xlabel('time since the plan started (s)')
    ax.set_ylabel('position error (cm)')
    ax.set_title(title)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
