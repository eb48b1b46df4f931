"""`quadflight fly MISSION.yaml`: fly a mission through the node graph in the lockstep simulator. A fleet mission (a
`vehicles:` list) flies through the fleet's graph: `quadflight fleet FLEET.yaml --graph` (commands/fleet.py)."""

import argparse
import os
import sys
from pathlib import Path

from quad_bringup.commands.plan import add_time_allocation_argument
from quad_bringup.commands.report import add_completion_arguments, completion_overrides
from quad_common.paths import input_path


def add_arguments(parser):
    parser.add_argument('mission', type=input_path,
                        help='mission YAML (waypoints, trajectory, world), e.g. config/missions/maze.yaml')
    parser.add_argument('--controller', metavar='NAME',
                        help="pd | pid | se3, or a user class: package.module:Class or a quadflight.controllers "
                             "entry point (docs/plugins.md); default: the control profile's, else pd")
    parser.add_argument('--speed', type=float, metavar='V',
                        help='average speed constant in m/s (overrides the mission)')
    add_time_allocation_argument(parser)
    parser.add_argument('--out', type=Path, help='run directory (default runs/<mission>-<controller>-<timestamp>)')
    parser.add_argument('--vehicle', type=input_path, help='vehicle YAML for controller and simulator')
    parser.add_argument('--plant', metavar='MEMBER',
                        help='simulate a plant family member (config/plant_family.yaml, e.g. autopilot_so3); '
                             'the controller still flies the vehicle file')
    parser.add_argument('--disturbances', metavar='PROFILE', help='simulator disturbance profile (e.g. drag_wind)')
    parser.add_argument('--control-profile', type=input_path, metavar='FILE',
                        help='params file overriding config/control.yaml gains (e.g. config/control_fast.yaml)')
    parser.add_argument('--state-source', choices=('odom', 'external_pose'),
                        help="what the controller flies from: odom (the simulator's state), or external_pose: the "
                             "simulator's motion-capture stand-in (1 mm, a frame per step), as in a lab "
                             '(default: the control profile\'s state_source, odom)')
    parser.add_argument('--time-limit-factor', type=float, default=3.0, metavar='K',
                        help='give up after K x the planned duration + 10 s of simulated time (default 3)')
    add_completion_arguments(parser)
    parser.add_argument('--fly-anyway', action='store_true',
                        help='fly a plan that fails the feasibility check on the vehicle (tilt, thrust, rotors, '
                             'attitude lag); without it such a plan is refused (exit 2)')
    parser.add_argument('--process-per-node', action='store_true',
                        help='every node its own process (as launch_ros starts them) instead of one process for '
                             'trajectory_node, sim_node and position_controller')
    parser.add_argument('--quiet', action='store_true', help='no progress lines')


def options_from(args):
    from quad_bringup.running.flight_options import FlightOptions

    return FlightOptions(mission=Path(args.mission), controller=args.controller, speed_mps=args.speed, out=args.out,
                         time_allocation=args.time_allocation,
                         vehicle=args.vehicle, plant=args.plant, disturbances=args.disturbances,
                         control_profile=args.control_profile, completion=completion_overrides(args),
                         time_limit_factor=args.time_limit_factor, quiet=args.quiet, fly_anyway=args.fly_anyway,
                         state_source=args.state_source, process_per_node=args.process_per_node)


# fly's options a fleet does not take: each vehicle's vehicle file, controller and profile are in the fleet file
NOT_FOR_FLEETS = ('controller', 'vehicle', 'plant', 'disturbances', 'control_profile', 'state_source')


def run_fleet(args) -> int:
    from quad_bringup.commands import fleet

    given = [name for name in NOT_FOR_FLEETS + ('position_tolerance', 'speed_tolerance', 'settle')
             if getattr(args, name) is not None]
    if given:
        print(f'quadflight fly: --{given[0].replace("_", "-")} {getattr(args, given[0])} refused: {args.mission} is a '
              'fleet mission (each vehicle names its vehicle file, controller and profile in it)', file=sys.stderr)
        return 2
    return fleet.run(argparse.Namespace(mission=Path(args.mission), out=args.out, speed=args.speed,
                                        time_allocation=args.time_allocation, disturbances='none',
                                        fly_anyway=args.fly_anyway, graph=True, process_per_node=args.process_per_node,
                                        no_figures=False))


# numpy's OpenBLAS starts a thread per core when numpy is imported, which spins after each call it serves: ~0.07 s of
# CPU in each of fly's processes (fly, node_host, the figures') on the 2-core machine, for matrices of 3 to ~100
# rows that one thread serves as fast (planning maze: 0.14 s of CPU against 0.22 s). Set before fly imports numpy,
# and inherited by every process it starts; a value the user set is kept.
BLAS_THREADS = {'OPENBLAS_NUM_THREADS': '1'}


def run(args) -> int:
    for name, value in BLAS_THREADS.items():
        os.environ.setdefault(name, value)
    from quad_bringup.running.flight import fly
    from quad_common.paths import resolve_config
    from quad_trajectory.mission_kind import is_fleet_file

    try:   # config/missions/... from any working directory, as the README writes it
        args.mission = resolve_config(args.mission)
    except FileNotFoundError:
        pass   # validate names it
    if is_fleet_file(args.mission):
        return run_fleet(args)
    result = fly(options_from(args), log=lambda line: print(line, flush=True), defer_figures=True)
    if result.metrics is not None:
        from quad_bringup.analysis.report import metrics_table

        print(metrics_table(result.metrics))
        for note in result.notes:
            print(note)
        print(f'run: {result.run_dir} (bag/, metrics.json, report.md, figures/)', flush=True)
    stream = sys.stdout if result.exit_code == 0 else sys.stderr
    word = {0: 'OK', 2: 'REFUSED'}.get(result.exit_code, 'FAILED')
    print(f'{word}: {result.reason}', file=stream, flush=True)
    if result.finish is not None:  # the figures after the verdict (their process imported during the flight)
        problem = result.finish()
        if problem:
            print(problem, file=sys.stderr, flush=True)
    return result.exit_code
