"""A simulated vehicle's diagnostics as a function of its simulator's state and its lockstep counts (no rclpy;
sim_node publishes them on the vehicle's `diagnostics` on an event and every DIAGNOSTICS_PERIOD_S of sim time).

Statuses: collision and vehicle collision (ERROR: the count, the first one's time, where the newest was),
failsafe (ERROR while active or when it began since the last report), saturation (WARN while the rotors limit the
command), stopped (ERROR: the reason), published (the distinct odom and /clock steps a bag is checked against, the
future-stamped setpoints refused) and the real-time factor.
"""

from quad_common import contract, diagnostics
from quad_sim.vehicle_contact import VEHICLE_COLLISION

DIAGNOSTICS_PERIOD_S = 1.0  # sim time between reports without an event
FAILSAFE_KINDS = ('failsafe', 'failsafe_cleared', 'disarmed')


class ReportSchedule:
    """When a vehicle's slower outputs are due at a published step: the sensors (/tf, imu, rotor_speeds) every
    sensor_period_ns of sim time (0: every step), its diagnostics on a new event or every DIAGNOSTICS_PERIOD_S."""

    def __init__(self, sensor_period_ns: int):
        self.sensor_period_ns = sensor_period_ns
        self.next_sensors_ns = self.next_diagnostics_ns = self.events_reported = 0

    def sensors_due(self, time_ns: int) -> bool:
        if time_ns >= self.next_sensors_ns:
            self.next_sensors_ns = time_ns + self.sensor_period_ns
            return True
        return False

    def diagnostics_due(self, time_ns: int, events: int) -> bool:
        return events > self.events_reported or time_ns >= self.next_diagnostics_ns

    def reported(self, time_ns: int, events: list) -> list:
        """A report at time_ns: the events new since the last one."""
        new, self.events_reported = events[self.events_reported:], len(events)
        self.next_diagnostics_ns = time_ns + int(DIAGNOSTICS_PERIOD_S * 1e9)
        return new


def place(event) -> dict:
    """Where an event happened (its time is the contract's *_time_s key, at full precision)."""
    return {'x': f'{event.position[0]:.3f}', 'y': f'{event.position[1]:.3f}',
            'z': f'{event.position[2]:.3f}', **event.detail}


def vehicle_statuses(sim, new_events, steps_published: int, future_setpoints: int, rtf: float) -> list:
    """The DiagnosticStatus list for `sim` (a Simulator: events, robot_radius_m, failsafe_active, saturation,
    saturated_steps, stopped); new_events: its events since the last report."""
    statuses = []
    collisions = [e for e in sim.events if e.kind == 'collision']
    if collisions:
        e = collisions[-1]
        statuses.append(diagnostics.status(contract.SIM_STATUS.format('collision'), diagnostics.ERROR,
                                           f'collision {len(collisions)}: within {sim.robot_radius_m} m '
                                           'of an obstacle', {contract.COLLISION_TIME_S: repr(collisions[0].time_s),
                                                               'collisions': len(collisions), **place(e)}))
    contacts = [e for e in sim.events if e.kind == VEHICLE_COLLISION]
    if contacts:
        e = contacts[-1]
        statuses.append(diagnostics.status(contract.SIM_STATUS.format(VEHICLE_COLLISION), diagnostics.ERROR,
                                           f'vehicle collision {len(contacts)}: with {e.detail["other"]}',
                                           {contract.COLLISION_TIME_S: repr(contacts[0].time_s),
                                            'collisions': len(contacts), **place(e)}))
    failsafe = [e for e in sim.events if e.kind in FAILSAFE_KINDS]
    if sim.failsafe_active or any(e.kind == 'failsafe' for e in new_events):
        e = failsafe[-1]
        statuses.append(diagnostics.status(contract.SIM_FAILSAFE, diagnostics.ERROR,
                                           f'setpoint lost: landing failsafe ({e.kind})',
                                           {contract.FAILSAFE_TIME_S: repr(e.time_s), **place(e)}))
    saturated = sim.saturation or any(e.kind == 'saturation' for e in new_events)
    statuses.append(diagnostics.status(
        contract.SIM_STATUS.format('saturation'), diagnostics.WARN if saturated else diagnostics.OK,
        f'rotor limits reduced {", ".join(sim.saturation) or "the command"}' if saturated else 'within limits',
        {'saturated_steps': sim.saturated_steps}))
    if sim.stopped is not None:
        statuses.append(diagnostics.status(contract.SIM_STATUS.format('stopped'), diagnostics.ERROR,
                                           str(sim.stopped), {'reason': sim.stopped.reason,
                                                              contract.STOP_TIME_S: repr(sim.stopped.time_s)}))
    statuses.append(diagnostics.status(
        contract.SIM_PUBLISHED, diagnostics.OK, 'distinct odom and /clock steps published (a bag '
        'is checked against it)', {'steps': steps_published, 'future_setpoints_refused': future_setpoints}))
    statuses.append(diagnostics.status(contract.SIM_STATUS.format('real_time_factor'), diagnostics.OK,
                                       f'{rtf:.2f}x', {'rtf': f'{rtf:.3f}'}))
    return statuses
