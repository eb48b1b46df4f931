"""The `quadflight` command: one entry point for planning, flying, recording and reporting."""

import argparse
import importlib
import importlib.util
import sys

__version__ = '0.1.0'

# name -> (module, help). Each module has add_arguments(parser) and run(args) -> exit code;
# a subcommand whose module is not there yet is not offered.
SUBCOMMANDS = {
    'plan': ('quad_bringup.commands.plan', 'plan a trajectory through a mission\'s waypoints (no flight)'),
    'fly': ('quad_bringup.commands.fly', 'fly a mission through the node graph in the simulator, record, report'),
    'record': ('quad_bringup.commands.record', 'record topics to a rosbag2 bag (MCAP)'),
    'report': ('quad_bringup.commands.report', 'metrics, tables and figures from a rosbag2 bag'),
    'identify': ('quad_bringup.commands.identify', 'attitude lag and thrust scale of the vehicle from a flight bag, '
                 'as a control profile'),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='quadflight',
        description='Plan smooth quadrotor trajectories through waypoints and fly them in the '
                    'built-in simulator or on PX4/ArduPilot vehicles (a ROS 2 Jazzy node suite).')
    parser.add_argument('--version', action='version', version=f'quadflight {__version__}')
    sub = parser.add_subparsers(dest='command', metavar='COMMAND')
    for name, (module_name, help_text) in SUBCOMMANDS.items():
        if importlib.util.find_spec(module_name) is None:
            continue
        module = importlib.import_module(module_name)
        p = sub.add_parser(name, help=help_text, description=help_text)
        module.add_arguments(p)
        p.set_defaults(run=module.run)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, 'run', None):
        parser.print_help()
        return 0
    return args.run(args)


if __name__ == '__main__':
    sys.exit(main())
