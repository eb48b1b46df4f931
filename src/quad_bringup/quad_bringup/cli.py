"""The `quadflight` command: one entry point for planning, flying, recording and reporting."""

import argparse
import sys

__version__ = '0.1.0'

# name -> (module, help). Each module has add_arguments(parser) and run(args) -> exit code.
SUBCOMMANDS = {}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='quadflight',
        description='Plan smooth quadrotor trajectories through waypoints and fly them in the '
                    'built-in simulator or on PX4/ArduPilot vehicles (a ROS 2 Jazzy node suite).')
    parser.add_argument('--version', action='version', version=f'quadflight {__version__}')
    sub = parser.add_subparsers(dest='command', metavar='COMMAND')
    for name, (module, help_text) in SUBCOMMANDS.items():
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
