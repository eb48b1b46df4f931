"""`quadflight identify BAG [--base PROFILE] [--out FILE]`: the vehicle's attitude lag and thrust scale from a
flight bag (sim or a real vehicle through the bridge), written as a control profile (quad_bringup.identify)."""

import sys
from pathlib import Path

import yaml
from rosbags.rosbag2 import ReaderError

from quad_bringup.identify import identify, profile
from quad_bringup.report import load_flight
from quad_common.yaml_io import load_yaml

DEFAULT_BASE = 'config/control_se3.yaml'


def add_arguments(parser):
    parser.add_argument('bag', help='rosbag2 bag directory with cmd/attitude_thrust and odom (e.g. runs/NAME/bag)')
    parser.add_argument('--base', type=Path, default=None, metavar='PROFILE',
                        help=f'control profile the identified values go into (default {DEFAULT_BASE})')
    parser.add_argument('--out', type=Path, metavar='FILE',
                        help='profile to write (default: BAG_profile.yaml next to the bag)')


def run(args) -> int:
    from quad_common.paths import resolve_config
    bag = Path(args.bag)
    try:
        base = load_yaml(args.base if args.base else resolve_config(DEFAULT_BASE)) or {}
        result = identify(load_flight(bag))
    except (FileNotFoundError, ValueError, ReaderError) as exc:
        print(f'quadflight identify: {exc}', file=sys.stderr)
        return 1
    out = args.out or bag.resolve().with_name(bag.resolve().name + '_profile.yaml')
    written = profile(result, base)
    out.write_text(f'# quadflight identify {bag}\n' + yaml.safe_dump(written, sort_keys=False))
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
    print(f'profile: {out} (attitude_lead_s {written["position_controller"]["ros__parameters"]["attitude_lead_s"]}, '
          f'thrust_scale {written["position_controller"]["ros__parameters"]["thrust_scale"]})')
    return 0
