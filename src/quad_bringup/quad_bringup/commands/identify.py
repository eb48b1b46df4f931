"""`quadflight identify BAG [--base PROFILE] [--out FILE] [--latency-s S] [--vehicle FILE]`: the vehicle's attitude
lag and thrust scale from a flight bag (sim or a real vehicle through the bridge; only the window in which the
vehicle flew our setpoints), written as a control profile (quad_bringup.identify) only when the fits hold and
that profile has margin on the lag it measured (quad_bringup.stability)."""

import sys
from pathlib import Path

from rosbags.rosbag2 import ReaderError

from quad_bringup.identify import identify, profile, profile_text, quality_refusal
from quad_bringup.report import load_flight
from quad_common.yaml_io import load_yaml

DEFAULT_BASE = 'config/control_real.yaml'            # what the bridge launch files fly
DEFAULT_VEHICLE = 'config/vehicles/px4_quad.yaml'    # the bridge's and the emulator's vehicle


def add_arguments(parser):
    from quad_bringup.stability import MARGIN_LAG, MARGIN_LATENCY, MEASURED_LATENCY_S
    parser.add_argument('bag', help='rosbag2 bag directory with cmd/attitude_thrust and odom (e.g. runs/NAME/bag)')
    parser.add_argument('--base', type=Path, default=None, metavar='PROFILE',
                        help=f'control profile the identified values go into (default {DEFAULT_BASE})')
    parser.add_argument('--out', type=Path, metavar='FILE',
                        help='profile to write (default: BAG_profile.yaml next to the bag)')
    parser.add_argument('--latency-s', type=float, default=MEASURED_LATENCY_S, metavar='S',
                        help=f'the vehicle\'s telemetry latency (default {MEASURED_LATENCY_S}, ArduCopter\'s); the '
                        f'profile must settle at {MARGIN_LAG}x the identified lag and {MARGIN_LATENCY}x this')
    parser.add_argument('--vehicle', type=Path, default=None, metavar='FILE',
                        help=f'vehicle file of the margin check (default {DEFAULT_VEHICLE})')


def run(args) -> int:
    import math

    from quad_bringup.closed_loop import control_profile
    from quad_bringup.stability import MARGIN_LAG, MARGIN_LATENCY, margin_hold
    from quad_common.paths import resolve_config
    bag = Path(args.bag)
    if not (math.isfinite(args.latency_s) and 0.0 <= args.latency_s <= 1.0):
        print(f'quadflight identify: --latency-s = {args.latency_s!r} must be a number in [0, 1] s', file=sys.stderr)
        return 1
    try:
        base = load_yaml(args.base if args.base else resolve_config(DEFAULT_BASE)) or {}
        vehicle = args.vehicle if args.vehicle else resolve_config(DEFAULT_VEHICLE)
        result = identify(load_flight(bag))
        written = profile(result, base)
        controller, gains = control_profile(written)
        # the vehicle as identified (thrust scale k), flown by the profile that divides by k
        margin = margin_hold(vehicle, controller, gains, result['attitude_lead_s'], args.latency_s,
                             thrust_error=result['thrust_scale'] - 1.0)
    except (FileNotFoundError, ValueError, ReaderError) as exc:
        print(f'quadflight identify: {exc}', file=sys.stderr)
        return 1
    w = result['window']
    print(f'window: {w["duration_s"]:.1f} s in which the vehicle flew our setpoints ({w["source"]}), '
          f'{w["start_s"]:.2f}-{w["end_s"]:.2f} s')
    for axis in ('roll', 'pitch'):
        a = result[axis]
        print(f'{axis:5s}: lag {a["lag_s"]:.3f} s (95 % {a["lag_ci95_s"][0]:.3f}-{a["lag_ci95_s"][1]:.3f}, '
              f'{a["blocks"]} parts) = tau {a["tau_s"]:.3f} s + dead time {a["delay_s"]:.3f} s; '
              f'bandwidth {a["bandwidth_hz"]:.2f} Hz; gain {a["gain"]:.3f}; fit R^2 {a["fit_r2"]:.3f}')
    t = result['thrust']
    low, high = t['thrust_scale_ci95']
    print(f'thrust: scale {t["thrust_scale"]:.4f} (95 % {low:.4f}-{high:.4f}); '
          f'hover at {t["hover_specific_force_mps2"]:.3f} m/s^2 commanded; equivalent mass error '
          f'{100 * t["mass_error_equivalent"]:+.1f} %')
    print(f'margin ({MARGIN_LAG}x the lag {result["attitude_lead_s"]:.3f} s, {MARGIN_LATENCY}x the telemetry latency '
          f'{args.latency_s:.3f} s, {controller}): {margin.describe()}')
    out = args.out or bag.resolve().with_name(bag.resolve().name + '_profile.yaml')
    refusal = quality_refusal(result)
    if refusal:
        print(f'quadflight identify: refused to write {out}: {refusal}', file=sys.stderr)
        return 1
    if not margin.settled:
        lost = f', {margin.stopped}' if margin.stopped else ''
        hint = f' (e.g. --base {DEFAULT_BASE})' if args.base else ''
        print(f'quadflight identify: refused to write {out}: the profile ({controller}, base '
              f'{args.base or DEFAULT_BASE}) does not settle at {margin.lag_s:.3f} s of attitude lag and '
              f'{margin.latency_s:.3f} s of telemetry latency (tilt {margin.late_tilt_deg:.1f} deg over the last '
              f'quarter, oscillation {margin.oscillation_deg:.2f} deg rms{lost}): start from softer gains{hint}',
              file=sys.stderr)
        return 1
    facts = {**result, 'margin': {'lag_s': round(margin.lag_s, 4), 'latency_s': round(margin.latency_s, 4),
                                  'late_tilt_deg': round(margin.late_tilt_deg, 3),
                                  'oscillation_deg': round(margin.oscillation_deg, 3),
                                  'offset_m': round(margin.offset_m, 4)}}
    out.write_text(profile_text(written, facts, f'quadflight identify {bag}'))
    print(f'profile: {out} (attitude_lead_s {written["position_controller"]["ros__parameters"]["attitude_lead_s"]}, '
          f'thrust_scale {written["position_controller"]["ros__parameters"]["thrust_scale"]})')
    return 0
