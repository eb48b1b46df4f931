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
from quad_control.parameters import profile_parameters

DEFAULT_BASE = 'config/control_real.yaml'            # what the bridge launch files fly
DEFAULT_VEHICLE = 'config/vehicles/px4_quad.yaml'    # the bridge's and the emulator's vehicle


HEADER = '# quadflight identify '   # the first line of every profile identify writes


def out_refusal(out: Path, inputs) -> str | None:
    """--out may replace only a profile identify wrote (issue 27.5: inputs are never modified)."""
    from quad_bringup.inputs import same_file
    for what, path in inputs:
        if path is not None and same_file(out, path):
            return f'--out {out} refused: it is the {what}, an input (never modified)'
    if out.is_dir():
        return f'--out {out} refused: a directory; name the profile file to write'
    if out.exists():
        try:
            ours = out.read_text(errors='replace').startswith(HEADER)
        except OSError:
            ours = False
        if not ours:
            return f'--out {out} refused: the file exists and was not written by quadflight identify: choose another'
    return None


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
    from quad_bringup.closed_loop import control_profile
    from quad_bringup.limits import refusal
    from quad_bringup.stability import MARGIN_LAG, MARGIN_LATENCY, margin_hold
    from quad_common.paths import resolve_config
    bag = Path(args.bag)
    out = args.out or bag.resolve().with_name(bag.resolve().name + '_profile.yaml')
    reason = refusal('latency_s', args.latency_s) or out_refusal(out, [('bag', bag), ('--base', args.base),
                                                                        ('--vehicle', args.vehicle)])
    if reason:
        print(f'quadflight identify: {reason}', file=sys.stderr)
        return 2
    try:
        base = load_yaml(args.base if args.base else resolve_config(DEFAULT_BASE)) or {}
        vehicle = args.vehicle if args.vehicle else resolve_config(DEFAULT_VEHICLE)
        result = identify(load_flight(bag))
        written = profile(result, base)
        controller, gains = control_profile(written)
        # the vehicle as identified (thrust scale k), flown by the profile that divides by k
        margin = margin_hold(vehicle, controller, gains, result['attitude_lead_s'], args.latency_s,
                             thrust_error=result['thrust_scale'] - 1.0)
    except (OSError, ValueError, ReaderError, StopIteration) as exc:
        why = str(exc) or 'none of the topics identify needs (odom, cmd/attitude_thrust) in it'
        print(f'quadflight identify: {bag}: {why}', file=sys.stderr)
        return 2
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
    poor = quality_refusal(result)
    if poor:
        print(f'quadflight identify: refused to write {out}: {poor}', file=sys.stderr)
        return 2
    if not margin.settled:
        lost = f', {margin.stopped}' if margin.stopped else ''
        hint = f' (e.g. --base {DEFAULT_BASE})' if args.base else ''
        print(f'quadflight identify: refused to write {out}: the profile ({controller}, base '
              f'{args.base or DEFAULT_BASE}) does not settle at {margin.lag_s:.3f} s of attitude lag and '
              f'{margin.latency_s:.3f} s of telemetry latency (tilt {margin.late_tilt_deg:.1f} deg over the last '
              f'quarter, oscillation {margin.oscillation_deg:.2f} deg rms{lost}): start from softer gains{hint}',
              file=sys.stderr)
        return 2
    facts = {**result, 'margin': {'lag_s': round(margin.lag_s, 4), 'latency_s': round(margin.latency_s, 4),
                                  'late_tilt_deg': round(margin.late_tilt_deg, 3),
                                  'oscillation_deg': round(margin.oscillation_deg, 3),
                                  'offset_m': round(margin.offset_m, 4)}}
    try:
        out.write_text(profile_text(written, facts, f'{HEADER.removeprefix("# ")}{bag}'))
    except OSError as exc:
        print(f'quadflight identify: --out {out}: cannot write it ({exc.strerror or exc})', file=sys.stderr)
        return 2
    values = profile_parameters(written)
    print(f'profile: {out} (attitude_lead_s {values["attitude_lead_s"]}, thrust_scale {values["thrust_scale"]})')
    return 0
