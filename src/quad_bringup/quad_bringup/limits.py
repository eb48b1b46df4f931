"""One set of limits for the numeric options of every command: fly, plan, report, identify and the
completion rule read these, so a value one command refuses no other accepts. Pure Python."""

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Limit:
    option: str            # how the user writes it
    low: float
    high: float
    unit: str = ''
    low_inclusive: bool = False

    def check(self, value, name: str | None = None) -> str | None:
        """The refusal naming the option (or `name`) and the value, or None."""
        number = not isinstance(value, bool) and isinstance(value, (int, float))
        if number and math.isfinite(value) and (self.low <= value if self.low_inclusive else self.low < value) \
                and value <= self.high:
            return None
        shown = f'{value:g}' if number else repr(value)
        return (f'{name or self.option} {shown} refused: must be {">=" if self.low_inclusive else ">"} '
                f'{self.low:g} and <= {self.high:g}{" " + self.unit if self.unit else ""} (a number)')


LIMITS = {
    'speed_mps': Limit('--speed', 0.0, 100.0, 'm/s'),
    'time_limit_factor': Limit('--time-limit-factor', 0.0, 1000.0),
    'position_tolerance_m': Limit('--position-tolerance', 0.0, 100.0, 'm'),
    'speed_tolerance_mps': Limit('--speed-tolerance', 0.0, 100.0, 'm/s'),
    'settle_s': Limit('--settle', 0.0, 1e6, 's', low_inclusive=True),
    'csv_rate_hz': Limit('--csv', 0.0, 1e6, 'Hz'),
    'latency_s': Limit('--latency-s', 0.0, 1.0, 's', low_inclusive=True),
    'divergence_m': Limit('divergence_m', 0.0, 1e6, 'm'),
    'startup_timeout_s': Limit('startup_timeout_s', 0.0, 1e6, 's'),
    'stall_timeout_s': Limit('stall_timeout_s', 0.0, 1e6, 's'),
}
# plan --csv writes rate x duration rows (13 numbers each, ~120 bytes in the file, 104 in memory): this many at
# most, ~120 MB, so a mission of 1e9 m cannot fill the disk or the memory.
CSV_MAX_SAMPLES = 1_000_000

# identify writes a profile only with margin (quad_bringup.offline.stability): it must settle at MARGIN_LAG x the
# identified attitude response and MARGIN_LATENCY x the telemetry latency
MEASURED_LAG_S = (0.17, 0.21)    # ArduCopter SITL roll/pitch under pd/pid
MEASURED_LATENCY_S = 0.05        # its telemetry
MARGIN_LAG = 1.5
MARGIN_LATENCY = 2.0
# PX4 v1.16 SITL + SIH, attitude setpoint -> attitude as a first order plus dead time (tau_s, dead_time_s): fits of
# 0.145-0.17 s / 0.09-0.11 s on the flights that did not oscillate (control_real, pd; R^2 0.99-1.00). A pure dead
# time, where the emulator's own shaping (first order + angle-P loop) has none at the same mean delay
PX4_SIH_ATTITUDE_RESPONSE_S = (0.15, 0.105)


# ROS_DOMAIN_ID: Fast DDS (the wheels' RMW) derives its ports from it and takes 0-232 (port 7400 + 250 x id + 11
# must stay below 65536); above it, it prints RTPS errors and the node cannot start
MAX_ROS_DOMAIN_ID = 232


def domain_refusal(environ) -> str | None:
    """The refusal of the environment's ROS_DOMAIN_ID (a command that joins that domain), or None."""
    text = environ.get('ROS_DOMAIN_ID', '').strip()
    if not text or text.isdigit() and int(text) <= MAX_ROS_DOMAIN_ID:
        return None
    return f'ROS_DOMAIN_ID={text!r} refused: must be an integer from 0 to {MAX_ROS_DOMAIN_ID} (Fast DDS\'s range)'


def ros_name_refusal(option: str, name: str, validate) -> str | None:
    """One line when rclpy's `validate` (validate_namespace, validate_topic_name) refuses `name`, else None."""
    try:
        validate(name)
    except Exception as exc:   # rclpy's InvalidNamespaceException / InvalidTopicNameException: a caret diagram
        reason = str(exc).splitlines()[0].rstrip(':').partition(': ')[2] or str(exc).splitlines()[0]
        return f'{option} {name!r} refused: {reason.split(", at /")[0]}'   # not rcl's source location
    return None


def refusal(key: str, value) -> str | None:
    """LIMITS[key]'s refusal of value (None: accepted, or not given)."""
    return None if value is None else LIMITS[key].check(value)


def csv_refusal(rate_hz: float, duration_s: float) -> str | None:
    """plan --csv: the rate's limit, then the rows it would write."""
    reason = refusal('csv_rate_hz', rate_hz)
    if reason:
        return reason
    rows = rate_hz * duration_s + 2
    if rows > CSV_MAX_SAMPLES:
        return (f'--csv {rate_hz:g} refused: {rate_hz:g} Hz x {duration_s:.6g} s planned = {rows:.3g} rows, above '
                f'{CSV_MAX_SAMPLES:,} (~120 MB); use a rate <= {CSV_MAX_SAMPLES / max(duration_s, 1e-9):.3g} Hz')
    return None
