"""The `quadflight` command: one entry point for planning, flying, recording and reporting."""

import argparse
import importlib
import importlib.util
import sys

from quad_bringup import __version__

# name -> (module, help). Each module has add_arguments(parser) and run(args) -> exit code;
# a subcommand whose module is not there yet is not offered.
SUBCOMMANDS = {
    'plan': ('quad_bringup.commands.plan', 'plan a trajectory through a mission\'s waypoints (no flight)'),
    'fly': ('quad_bringup.commands.fly', 'fly a mission through the node graph in the simulator, record, report'),
    'fleet': ('quad_bringup.commands.fleet', 'plan a fleet mission, check its separation and fly every vehicle '
                                             'offline in lockstep (no ROS yet): per-vehicle verdicts, collisions'),
    'record': ('quad_bringup.commands.record', 'record topics to a rosbag2 bag (MCAP)'),
    'report': ('quad_bringup.commands.report', 'metrics, tables and figures from a rosbag2 bag'),
    'identify': ('quad_bringup.commands.identify', 'attitude lag and thrust scale of the vehicle from a flight bag, '
                 'as a control profile (written when it has margin on that lag) and a vehicle model'),
    'replay': ('quad_bringup.commands.replay', "a flight's twin: its plan flown again in the simulator on a vehicle "
                                               'model (closed loop) and its setpoints open loop; RMSEs, a figure'),
    'sweep': ('quad_bringup.commands.sweep', 'many flights over missions x controllers x vehicles x disturbances x '
                                             'seeds: one table, a summary, figures'),
    'tune': ('quad_bringup.commands.tune', "search a controller's gains for a robust cost over missions and a "
                                           'plant family; write the profile, verify it through the graph'),
    'arm': ('quad_bringup.commands.vehicle', 'the bridge\'s arm service (--off disarms); no ros2 CLI needed'),
    'offboard': ('quad_bringup.commands.vehicle', 'the bridge\'s offboard service: hand the vehicle to the '
                                                  'controller (--off ends it)'),
    'land': ('quad_bringup.commands.vehicle', 'the bridge\'s land service'),
}


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The parser; only the module of `only` (a subcommand name) is imported, none for the top-level help: a help
    page or a refusal must not pay for rclpy, scipy or the flight graph (each command's module imports only
    argparse's needs at its top, the rest in run())."""
    parser = argparse.ArgumentParser(
        prog='quadflight',
        description='Plan smooth quadrotor trajectories through waypoints and fly them in the '
                    'built-in simulator or on PX4/ArduPilot vehicles (a ROS 2 Jazzy node suite).')
    parser.add_argument('--version', action='version', version=f'quadflight {__version__}')
    sub = parser.add_subparsers(dest='command', metavar='COMMAND')
    for name, (module_name, help_text) in SUBCOMMANDS.items():
        if importlib.util.find_spec(module_name) is None:
            continue
        if name != only:
            sub.add_parser(name, help=help_text, description=help_text)
            continue
        module = importlib.import_module(module_name)
        p = sub.add_parser(name, help=help_text, description=help_text)
        module.add_arguments(p)
        p.set_defaults(run=module.run)
    return parser


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(argv[0] if argv and argv[0] in SUBCOMMANDS else None)
    args = parser.parse_args(argv)
    if not getattr(args, 'run', None):
        parser.print_help()
        return 0
    try:
        return args.run(args)
    except KeyboardInterrupt:   # a command that keeps something on Ctrl-C catches it itself (fly, sweep, tune)
        print(f'quadflight {args.command}: interrupted', file=sys.stderr)
        return 130
    except OSError as exc:      # one line, never a traceback
        where = f'{exc.filename}: ' if exc.filename else ''
        print(f'quadflight {args.command}: {where}{exc.strerror or exc}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
