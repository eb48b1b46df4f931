"""`quadflight identify BAG [--base PROFILE] [--out FILE] [--latency-s S] [--vehicle FILE]`: the vehicle's attitude
lag and thrust scale from a flight bag (sim or a real vehicle through the bridge; only the window in which the
vehicle flew our setpoints), written as a control profile (quad_bringup.analysis.identify) only when the fits hold and
that profile has margin on the response it measured, with the bag's telemetry (quad_bringup.offline.stability)."""

import sys
from pathlib import Path

from quad_common.paths import input_path

DEFAULT_BASE = 'config/control_real.yaml'            # what the bridge launch files fly
DEFAULT_VEHICLE = 'config/vehicles/px4_quad.yaml'    # the bridge's and the emulator's vehicle


HEADER = '# quadflight identify '   # the first line of every profile identify writes


def out_refusal(out: Path, inputs) -> str | None:
    """--out may replace only a profile identify wrote (inputs are never modified)."""
    from quad_bringup.checks.inputs import same_file
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
    from quad_bringup.limits import MARGIN_LAG, MARGIN_LATENCY, MEASURED_LATENCY_S
    parser.add_argument('bag', help='rosbag2 bag directory with cmd/attitude_thrust and odom (e.g. runs/NAME/bag)')
    parser.add_argument('--base', type=input_path, default=None, metavar='PROFILE',
                        help=f'control profile the identified values go into (default {DEFAULT_BASE})')
    parser.add_argument('--out', type=Path, metavar='FILE',
                        help='profile to write (default: BAG_profile.yaml next to the bag)')
    parser.add_argument('--latency-s', type=float, default=None, metavar='S',
                        help='the vehicle\'s telemetry latency (default: the bag\'s: 0 for a simulator\'s lockstep '
                        f'bag, a vehicle\'s record - stamp delay but at least {MEASURED_LATENCY_S}, ArduCopter\'s); '
                        f'the profile must settle at {MARGIN_LAG}x the identified response and {MARGIN_LATENCY}x this')
    parser.add_argument('--soften', action='store_true',
                        help='where the base does not settle at the margin, scale its horizontal kp and ki down in '
                        'steps of 10 %% (to half at most) and write the first profile that settles, saying by how much')
    parser.add_argument('--vehicle', type=input_path, default=None, metavar='FILE',
                        help=f'vehicle file of the margin check and of the model (default {DEFAULT_VEHICLE})')
    parser.add_argument('--model-out', type=Path, metavar='FILE',
                        help='vehicle model to write beside the profile (default: BAG_vehicle.yaml next to the bag): '
                        '--vehicle with the identified attitude response and thrust, for fly --vehicle and sweeps')


def check_bag(bag, base_path=None, vehicle=None, latency_s: float | None = None, quality_first=False,
              soften=False) -> dict:
    """What `quadflight identify` decides on a bag: {'result': identify's, 'written': the profile, 'controller',
    'telemetry': stability.Telemetry, 'margin': stability.Hold, 'refusal': one line or None, 'softened': the factor
    on the base's horizontal kp and ki, 1 unless soften}. The margin check flies the profile on the response
    identified (stability.margin_hold_identified) with the bag's telemetry; soften: a base that does not settle is
    softened (identify.SOFTEN_FACTORS) until one does.
    base_path / vehicle: None for DEFAULT_BASE / DEFAULT_VEHICLE. Raises ValueError / OSError / ReaderError for a
    bag that cannot be identified. quality_first: fits that do not hold (identify.quality_refusal) end it there,
    with 'margin' None (the margin check flies seconds of simulation)."""
    from quad_bringup.analysis.identify import (
        SOFTEN_FACTORS,
        identify,
        identify_drag,
        profile,
        quality_refusal,
        softened,
    )
    from quad_bringup.analysis.report import load_flight
    from quad_bringup.offline.closed_loop import control_profile
    from quad_bringup.offline.stability import Telemetry, margin_hold_identified
    from quad_common.paths import resolve_config
    from quad_common.vehicle import load_vehicle
    from quad_common.yaml_io import load_yaml

    base = load_yaml(resolve_config(base_path or DEFAULT_BASE)) or {}   # a config/ name as --base does
    vehicle = vehicle if vehicle else resolve_config(DEFAULT_VEHICLE)
    flight = load_flight(bag)
    result = identify(flight)
    if quality_first and (refusal := quality_refusal(result)) is not None:
        return {'result': result, 'refusal': refusal, 'margin': None}
    result['drag'] = identify_drag(flight, result['thrust_scale'], load_vehicle(vehicle))
    written = profile(result, base)
    controller, gains = control_profile(written)
    telemetry = Telemetry.of_flight(flight, latency_s)
    # the vehicle as identified (its response, thrust scale k), flown by the profile that divides by k
    margin = margin_hold_identified(vehicle, controller, gains, result, telemetry)
    refusal = quality_refusal(result)
    factor, base_gains = 1.0, gains
    if soften and refusal is None and not margin.settled:
        for factor in SOFTEN_FACTORS:
            written = softened(written, base_gains, factor)
            controller, gains = control_profile(written)
            margin = margin_hold_identified(vehicle, controller, gains, result, telemetry)
            if margin.settled:
                break
    if refusal is None and not margin.settled:
        lost = f', {margin.stopped}' if margin.stopped else ''
        soft = f', even with its horizontal kp and ki x{factor:g}' if factor != 1.0 else ''
        refusal = (f'the profile ({controller}, base {base_path or DEFAULT_BASE}{soft}) does not settle at '
                   f'{margin.lag_s:.3f} s of attitude lag and {margin.latency_s:.3f} s of telemetry latency at '
                   f'{telemetry.rate_hz:.0f} Hz with bursts up to {telemetry.burst_s:.3f} s (tilt '
                   f'{margin.late_tilt_deg:.1f} deg over the last quarter, oscillation '
                   f'{margin.oscillation_deg:.2f} deg rms{lost}; telemetry from {telemetry.source})')
    return {'result': result, 'written': written, 'controller': controller, 'telemetry': telemetry,
            'margin': margin, 'refusal': refusal, 'vehicle': vehicle, 'softened': factor, 'base_gains': base_gains}


def print_fits(result: dict):
    """The window, the roll and pitch fits and the thrust scale, as measured."""
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


def run(args) -> int:
    from quad_bringup.checks.inputs import check_bag_dir
    from quad_bringup.limits import MARGIN_LAG, MARGIN_LATENCY, refusal

    bag = Path(args.bag)
    out = args.out or bag.resolve().with_name(bag.resolve().name + '_profile.yaml')
    model_out = args.model_out or bag.resolve().with_name(bag.resolve().name + '_vehicle.yaml')
    inputs = [('bag', bag), ('--base', args.base), ('--vehicle', args.vehicle)]
    reason = (refusal('latency_s', args.latency_s) if args.latency_s is not None else None) or out_refusal(
        out, inputs) or out_refusal(model_out, inputs + [('--out', out)])
    if not reason:
        try:
            check_bag_dir(bag)   # before the readers and the fits are imported (seconds)
        except OSError as exc:
            reason = f'{bag}: {exc}'
    if reason:
        print(f'quadflight identify: {reason}', file=sys.stderr)
        return 2
    from rosbags.rosbag2 import ReaderError

    from quad_bringup.analysis.identify import SOFTENED_GAINS, model_text, profile_text, quality_refusal, vehicle_model
    from quad_control.parameters import profile_parameters

    try:
        checked = check_bag(bag, args.base, args.vehicle, args.latency_s, quality_first=True, soften=args.soften)
    except (OSError, ValueError, ReaderError, StopIteration) as exc:
        why = str(exc) or 'none of the topics identify needs (odom, cmd/attitude_thrust) in it'
        print(f'quadflight identify: {bag}: {why}', file=sys.stderr)
        return 2
    if checked['margin'] is None:   # the fits do not hold: what it measured, and one line saying what is missing
        print_fits(checked['result'])
        print(f'quadflight identify: refused to write {out}: {checked["refusal"]}', file=sys.stderr)
        return 2
    result, written, margin, telemetry = checked['result'], checked['written'], checked['margin'], \
        checked['telemetry']
    print_fits(result)
    d = result['drag']
    print(f'drag: rotor drag {d["rotor_drag_xy"]:.3g} N/(m/s)/(rad/s) (95 % {d["rotor_drag_xy_ci95"][0]:.3g}-'
          f'{d["rotor_drag_xy_ci95"][1]:.3g}): {d["deceleration_per_mps_at_hover"]:.3f} m/s^2 per m/s at hover')
    print(f'telemetry: {telemetry.describe()}')
    print(f'margin ({MARGIN_LAG}x the response, tau + dead time {result["attitude_lead_s"]:.3f} s, {MARGIN_LATENCY}x '
          f'the telemetry latency {telemetry.latency_s:.3f} s, {checked["controller"]}): {margin.describe()}')
    if checked['refusal']:
        hint = f' (e.g. --base {DEFAULT_BASE})' if args.base and not quality_refusal(result) else ''
        hint += ', or --soften' if not args.soften and not quality_refusal(result) else ''
        soft = ': start from softer gains' if not quality_refusal(result) else ''
        print(f'quadflight identify: refused to write {out}: {checked["refusal"]}{soft}{hint}', file=sys.stderr)
        return 2
    if checked['softened'] != 1.0:
        base, values = checked['base_gains'], profile_parameters(written)
        print(f'softened: the base does not settle at the margin, its horizontal kp and ki x{checked["softened"]:g} '
              'do: ' + ', '.join(f'{name}_{axis} {float(getattr(base, name)[i]):g} -> {values[f"{name}_{axis}"]:g}'
                                 for name in SOFTENED_GAINS for i, axis in enumerate('xy')))
    facts = {**result, **({'softened': checked['softened']} if checked['softened'] != 1.0 else {}),
             'margin': {'lag_s': round(margin.lag_s, 4), 'latency_s': round(margin.latency_s, 4),
                        'late_tilt_deg': round(margin.late_tilt_deg, 3),
                        'oscillation_deg': round(margin.oscillation_deg, 3), 'offset_m': round(margin.offset_m, 4)}}
    model = vehicle_model(result, checked['vehicle'])
    for flag, path, text in (('--out', out, profile_text(written, facts, f'{HEADER.removeprefix("# ")}{bag}')),
                             ('--model-out', model_out, model_text(model, result,
                                                                   f'{HEADER.removeprefix("# ")}{bag}'))):
        try:
            path.write_text(text)
        except OSError as exc:
            print(f'quadflight identify: {flag} {path}: cannot write it ({exc.strerror or exc})', file=sys.stderr)
            return 2
    values = profile_parameters(written)
    print(f'profile: {out} (attitude_lead_s {values["attitude_lead_s"]}, thrust_scale {values["thrust_scale"]})')
    print(f'vehicle model: {model_out} (attitude_loop lag {model["attitude_loop"]["time_constant_s"]} s, thrust_error '
          f'{model["thrust_error"]}; fly --vehicle, a sweep\'s vehicles:)')
    return 0
