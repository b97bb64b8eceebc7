"""`memo-ros`: one command for simulation, bags, echo, evaluation and benchmarks.

Each sub-command lives in its own module exposing ``add_arguments(parser)`` and
``run(args) -> int``; errors a user can cause raise :class:`CliError` and end as
one line on stderr with a non-zero exit, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

# name -> (module, one-line help)
COMMANDS = {
    'simulate': (
        'memo_ros.tools.simulate',
        'render a simulated scenario into a rosbag2 with ground truth',
    ),
    'bag': ('memo_ros.tools.bag.cli', 'inspect, play and record rosbag2 files over DDS'),
    'echo': ('memo_ros.tools.echo', 'print messages of a topic as YAML (or CSV rows)'),
    'launch': (
        'memo_ros.tools.launch',
        'start the graph for a studio: one contour_node per camera',
    ),
    'replay': ('memo_ros.tools.replay', 'run a bag through the live graph and record its outputs'),
    'evaluate': ('memo_ros.tools.evaluate', 'score estimated poses against ground truth'),
    'benchmark': ('memo_ros.tools.benchmarks.cli', 'measure speed of the core and tools'),
    'import': (
        'memo_ros.tools.import_videos',
        'import recorded videos and their calibration into a bag and studio',
    ),
    'export': (
        'memo_ros.tools.export_videos',
        "export a bag's images as videos plus a calibration for other tools",
    ),
}


class CliError(Exception):
    """An error caused by the user's input: printed as one line, exit code 2."""


def build_parser() -> argparse.ArgumentParser:
    """Build the `memo-ros` parser with one sub-command per tool."""
    parser = argparse.ArgumentParser(prog='memo-ros', description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest='command', metavar='COMMAND')
    sub.required = True
    for name, (module_name, help_text) in COMMANDS.items():
        module = importlib.import_module(module_name)
        sub_parser = sub.add_parser(
            name, help=help_text, description=module.__doc__.splitlines()[0]
        )
        module.add_arguments(sub_parser)
        sub_parser.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run `memo-ros ARGS`; every failure ends in one line on stderr and exit 2."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        print('memo-ros: interrupted', file=sys.stderr)
        return 130
    except BrokenPipeError:  # `memo-ros bag info BAG | head`: the reader left, nothing to say
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 0
    except CliError as exc:
        print(f'memo-ros {args.command}: error: {" ".join(str(exc).split())}', file=sys.stderr)
        return 2
    except UnicodeDecodeError as exc:
        print(
            f'memo-ros {args.command}: error: a file given is not text (UTF-8): '
            f'byte {exc.start} cannot be decoded',
            file=sys.stderr,
        )
        return 2
    except (OSError, ValueError) as exc:  # a bad file or value: its message says which
        print(f'memo-ros {args.command}: error: {" ".join(str(exc).split())}', file=sys.stderr)
        return 2
    except Exception as exc:  # noqa: BLE001 - a tool run ends in one line, never a traceback
        if os.environ.get('MEMO_ROS_DEBUG'):
            raise
        print(
            f'memo-ros {args.command}: internal error: {type(exc).__name__}: '
            f'{" ".join(str(exc).split())} (MEMO_ROS_DEBUG=1 shows the traceback)',
            file=sys.stderr,
        )
        return 2


if __name__ == '__main__':
    # run the importable module's main, so CliError raised by sub-commands is the class caught here
    from memo_ros.tools.cli import main as _main

    sys.exit(_main())
