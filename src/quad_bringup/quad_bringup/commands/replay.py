"""`quadflight replay BAG [--vehicle MODEL.yaml] [--control-profile FILE] [--figure PNG]`: the flight's twin
(quad_bringup.offline.replay): its plan flown again in the simulator on the model, closed loop with the controller and
gains, and its setpoints open loop; prints the RMSEs and writes a figure."""

import sys
from pathlib import Path

from quad_common.paths import input_path

DEFAULT_PROFILE = 'config/control.yaml'


def add_arguments(parser):
    parser.add_argument('bag', help='rosbag2 bag with trajectory, odom and cmd/attitude_thrust (e.g. runs/NAME/bag)')
    parser.add_argument('--vehicle', type=input_path, metavar='MODEL',
                        help='vehicle model to fly (e.g. the BAG_vehicle.yaml identify wrote; default: the one '
                        'identify wrote next to the bag)')
    parser.add_argument('--control-profile', type=input_path, metavar='FILE',
                        help=f'the controller and gains the flight flew (default {DEFAULT_PROFILE})')
    parser.add_argument('--figure', type=Path, metavar='PNG', help='figure to write (default BAG_replay.png)')


def run(args) -> int:
    from quad_bringup.checks.inputs import check_bag_dir
    from quad_common.paths import resolve_config

    bag = Path(args.bag).resolve()
    vehicle = args.vehicle or bag.with_name(bag.name + '_vehicle.yaml')
    figure = args.figure or bag.with_name(bag.name + '_replay.png')
    reason = None
    if args.vehicle is None and not Path(vehicle).is_file():
        reason = (f'no vehicle model beside it ({vehicle.name}): quadflight identify {args.bag} writes it, or give '
                  '--vehicle MODEL.yaml')
    elif not Path(vehicle).is_file():
        reason = f'--vehicle {vehicle}: no such file'
    else:
        try:
            check_bag_dir(bag)
        except OSError as exc:
            reason = str(exc)
    if reason:   # before the bag's readers, the simulator and the controller are imported
        print(f'quadflight replay: {args.bag}: {reason}', file=sys.stderr)
        return 2
    from rosbags.rosbag2 import ReaderError

    from quad_bringup.analysis.report import load_flight
    from quad_bringup.offline.closed_loop import load_control_profile
    from quad_bringup.offline.replay import RMSE_GOAL, replay, write_figure

    try:
        controller, gains = load_control_profile(args.control_profile or resolve_config(DEFAULT_PROFILE))
        result = replay(load_flight(bag), vehicle, controller, gains)
    except (OSError, ValueError, ReaderError) as exc:
        print(f'quadflight replay: {args.bag}: {exc}', file=sys.stderr)
        return 2
    print(f'closed loop ({controller}, {vehicle}): flight RMSE {100 * result["flight_rmse_m"]:.2f} cm, twin RMSE '
          f'{100 * result["twin_rmse_m"]:.2f} cm ({100 * (result["rmse_ratio"] - 1):+.0f} %, goal within '
          f'{RMSE_GOAL:.0%}); |twin - flight| RMSE {100 * result["trace_rmse_m"]:.2f} cm')
    if result['telemetry_age_s']:
        flown_ms = 1000 * (result['telemetry_age_s'] + 0.5 * result['telemetry_period_s'])
        print(f'the twin\'s controller flew odometry {flown_ms:.0f} ms old on average, {result["telemetry_source"]}')
    print(f'open loop (the recorded setpoints, first {result["open_loop_s"]:.1f} s): |twin - flight| RMSE '
          f'{100 * result["open_trace_rmse_m"]:.2f} cm')
    if result['stopped']:
        print(f'the twin stopped: {result["stopped"]}')
    try:
        write_figure(result, figure, f'replay of {args.bag}')
    except OSError as exc:
        print(f'quadflight replay: --figure {figure}: cannot write it ({exc.strerror or exc})', file=sys.stderr)
        return 2
    print(f'figure: {figure}')
    return 0
