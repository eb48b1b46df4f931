"""Why the shipped motor time constants are what they are: the attitude loop behind a lagging motor.

Linearised about hover, one axis, the onboard PD u = I (kp e - kd omega) acts through the first-order
motor lag (moment M' = (u - M) / tau_m) on I phi'' = M, so per unit inertia

    tau_m s^3 + s^2 + kd s + kp = 0          (tau_m = 0:  s^2 + kd s + kp = 0)

Routh-Hurwitz: stable iff kd > tau_m kp, but the oscillatory pair loses damping long before that; the
seed's kp 3000, kd 300 give zeta ~ 0.03 behind rotorpy's 72 ms (a 64 rad/s ring that saturates the rotors
and crashes in the nonlinear simulator), ~ 0.2 at 15 ms.
"""

import numpy as np

MIN_DAMPING_RATIO = 0.15


def attitude_loop_poles(kp: float, kd: float, motor_time_constant_s: float) -> np.ndarray:
    """Closed-loop poles (rad/s) of one attitude axis."""
    coefficients = [motor_time_constant_s, 1.0, kd, kp] if motor_time_constant_s > 0 else [1.0, kd, kp]
    return np.roots(coefficients)


def damping_ratio(poles) -> float:
    """Smallest damping ratio -Re(s) / |s| among the poles (negative: unstable)."""
    poles = np.asarray(poles)
    return float(np.min(-poles.real / np.abs(poles)))


def attitude_damping(vehicle) -> float:
    """The worst damping ratio over the vehicle's three attitude axes, for its own onboard loop (eq. 6, the SO(3)
    cascade as kp = angle_p rate_p, kd = rate_p, or the lag loop's inner eq. 6; the lag's filter is a stable
    first-order pole in series) and its own motor lag."""
    kps, kds = vehicle.effective_attitude_gains()
    return min(damping_ratio(attitude_loop_poles(kp, kd, vehicle.motor_time_constant_s))
               for kp, kd in zip(kps, kds))


def attitude_mean_delay_s(vehicle, axis: int = 0) -> float:
    """Mean delay -G'(0) / G(0) of the onboard loop's attitude response G to an attitude setpoint without
    roll/pitch rate feed-forward: what a first-order-plus-dead-time fit calls tau + dead time.
    eq6: G = kp / (tau_m s^3 + s^2 + kd s + kp), mean delay kd / kp (the motor lag adds none);
    so3_pd: the same with kp = angle_p rate_p, kd = rate_p: 1 / angle_p;
    lag: the target's first order (time_constant_s), tracked with its own rate fed forward (no further delay)."""
    loop = vehicle.attitude_loop
    if loop.type == 'lag':
        return float(loop.time_constant_s)
    kp, kd = vehicle.effective_attitude_gains()
    return float(kd[axis] / kp[axis])


def largest_time_constant(kp: float, kd: float, min_damping: float = MIN_DAMPING_RATIO) -> float:
    """The largest tau_m (s) keeping the attitude loop's damping ratio >= min_damping (bisection)."""
    lo, hi = 0.0, kd / kp  # at kd / kp the loop is marginally stable
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if damping_ratio(attitude_loop_poles(kp, kd, mid)) >= min_damping else (lo, mid)
    return lo


def table(kp=3000.0, kd=300.0, time_constants_s=(0.0, 0.01, 0.015, 0.02, 0.03, 0.05, 0.072)) -> str:
    """Markdown table of the poles and damping against tau_m (docs/quad_sim.md)."""
    rows = ['| tau_m (s) | closed-loop poles (rad/s) | min damping ratio |', '|---|---|---|']
    for tau in time_constants_s:
        poles = attitude_loop_poles(kp, kd, tau)
        text = ', '.join(f'{p.real:.1f}{p.imag:+.1f}j' if abs(p.imag) > 1e-9 else f'{p.real:.1f}' for p in poles)
        rows.append(f'| {tau:g} | {text} | {damping_ratio(poles):.3f} |')
    return '\n'.join(rows)


if __name__ == '__main__':
    print(table())
    print(f'largest tau_m with damping >= {MIN_DAMPING_RATIO}: {largest_time_constant(3000.0, 300.0):.4f} s')
