"""`memo-ros bag info|play|record`: the sub-commands and their options."""

from __future__ import annotations

import argparse
from pathlib import Path

from memo_ros.ros.bagio import STORAGE_PLUGINS, BagError
from memo_ros.ros.dds import (
    DURABILITY,
    RELIABILITY,
)
from memo_ros.ros.messages import MessageTypeError
from memo_ros.tools.bag.info import run_info
from memo_ros.tools.bag.play import run_play
from memo_ros.tools.bag.record import run_record


def _positive(text: str) -> float:
    """Argparse type: a number > 0."""
    value = float(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f'must be positive, not {text}')
    return value


def _not_negative(text: str) -> float:
    """Argparse type: a number >= 0."""
    value = float(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f'must not be negative, not {text}')
    return value


def _count(text: str) -> int:
    """Argparse type: an integer >= 1."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f'must be at least 1, not {text}')
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Return the info, play and record sub-commands and their options."""
    sub = parser.add_subparsers(dest='bag_command', metavar='{info,play,record}')
    sub.required = True

    info = sub.add_parser(
        'info',
        help='show storage, duration, time span and per-topic counts of a bag',
        description='Show what a rosbag2 holds, like `ros2 bag info`.',
    )
    info.add_argument('bag', type=Path, help='bag directory (or a single .mcap/.db3 file)')
    info.set_defaults(_bag_run=run_info)

    play = sub.add_parser(
        'play',
        help='publish the messages of a bag with the recorded timing',
        description='Publish the recorded serialized messages of a bag over DDS.',
    )
    play.add_argument('bag', type=Path, help='bag directory (or a single .mcap/.db3 file)')
    play.add_argument(
        '--rate',
        '-r',
        type=_not_negative,
        default=1.0,
        help='playback speed factor (default 1; 0 = as fast as possible)',
    )
    play.add_argument(
        '--max-speed', action='store_true', help='publish as fast as possible (same as --rate 0)'
    )
    play.add_argument(
        '--loop', '-l', action='store_true', help='start again at the end, until interrupted'
    )
    play.add_argument(
        '--start-offset',
        type=_not_negative,
        default=0.0,
        metavar='SECONDS',
        help='start this many seconds into the bag',
    )
    play.add_argument('--topics', nargs='+', metavar='TOPIC', help='play only these topics')
    play.add_argument(
        '--remap',
        action='append',
        default=[],
        metavar='OLD:=NEW',
        help='publish topic OLD of the bag on NEW (repeatable)',
    )
    play.add_argument(
        '--wait-for-subscribers',
        type=int,
        default=0,
        metavar='N',
        help='before playing, wait until every topic has at least N matched subscribers',
    )
    play.add_argument(
        '--wait-timeout',
        type=_positive,
        default=30.0,
        metavar='SECONDS',
        help='give up waiting for subscribers after this long (default 30)',
    )
    play.add_argument(
        '--qos', choices=sorted(RELIABILITY), default='reliable', help='publisher reliability'
    )
    play.add_argument(
        '--qos-depth', type=_count, default=100, help='publisher history depth (default 100)'
    )
    play.add_argument(
        '--durability', choices=sorted(DURABILITY), default='volatile', help='publisher durability'
    )
    play.add_argument(
        '--progress', action='store_true', help='show progress even when stderr is not a terminal'
    )
    play.set_defaults(_bag_run=run_play)

    record = sub.add_parser(
        'record',
        help='record topics into a bag (mcap, as received on the wire)',
        description='Record the serialized messages of topics into a new rosbag2.',
    )
    record.add_argument('topics', nargs='*', metavar='TOPIC', help='topics to record')
    record.add_argument(
        '--all',
        '-a',
        action='store_true',
        help='record every topic, including ones appearing later',
    )
    record.add_argument(
        '--exclude', metavar='REGEX', help='with --all, leave out topics matching REGEX'
    )
    record.add_argument(
        '-o', '--output', type=Path, required=True, help='bag directory to create (must not exist)'
    )
    record.add_argument(
        '--storage', choices=sorted(STORAGE_PLUGINS), default='mcap', help='storage format'
    )
    record.add_argument(
        '--max-messages', type=_count, metavar='N', help='stop after N messages in all'
    )
    record.add_argument(
        '--duration', type=_positive, metavar='SECONDS', help='stop after this long'
    )
    record.add_argument(
        '--idle-timeout',
        type=_positive,
        metavar='SECONDS',
        help='stop when no message arrived for this long (once one did)',
    )
    record.add_argument(
        '--qos',
        choices=['auto'] + sorted(RELIABILITY),
        default='auto',
        help='subscription reliability (auto: reliable when every publisher is)',
    )
    record.add_argument(
        '--qos-depth', type=_count, default=100, help='subscription history depth (default 100)'
    )
    record.add_argument(
        '--progress',
        action='store_true',
        help='show a status line even when stderr is not a terminal',
    )
    record.set_defaults(_bag_run=run_record)


def run(args: argparse.Namespace) -> int:
    """Run the chosen sub-command; bag and type problems become one-line CLI errors."""
    from memo_ros.tools.cli import CliError

    try:
        return args._bag_run(args)
    except (BagError, MessageTypeError) as exc:
        raise CliError(str(exc)) from None
