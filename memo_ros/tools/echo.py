"""Print messages of a topic as YAML like `ros2 topic echo`, or as CSV rows.

PointCloud2 points as a table.

The type comes from the graph unless given.  YAML mode abbreviates long numeric arrays (image and
cloud ``data``) unless ``--full`` and adds a table of a cloud's points (``--max-rows``).  CSV mode
prints a header line of flattened field names, then one line per message, or one line per point of
a cloud. A camera assignment (``/memo/camera_assignment``) prints as its part x camera table
(``--full``: the raw DiagnosticArray), in CSV one line per part and camera.
"""

from __future__ import annotations

import argparse
from collections import deque
import csv
import os
import sys
import time
from typing import TextIO

from sensor_msgs.msg import PointCloud2

from memo_ros.ros.assignment_messages import (
    assignment_rows,
    assignment_table,
    is_assignment_message,
)
from memo_ros.ros.dds import (
    RELIABILITY,
    absolute_topic,
    adapted_qos,
    ros_session,
    stop_on_signals,
    wait_for_topic_type,
)
from memo_ros.ros.messages import (
    DEFAULT_TRUNCATE,
    MessageTypeError,
    flatten_message,
    format_cell,
    import_message_type,
    message_to_yaml,
)
from memo_ros.ros.pointcloud import pointcloud_to_array, table_columns

YAML_MAX_ROWS = 20


class CsvPrinter:
    """Writes messages as CSV lines, with a header line whenever the columns change."""

    def __init__(self, out: TextIO, max_array_length: int | None, max_rows: int | None) -> None:
        self._writer = csv.writer(out, lineterminator='\n')
        self._max_array_length = max_array_length
        self._max_rows = max_rows
        self._columns: list[str] | None = None

    def _header(self, columns: list[str]) -> None:
        """Write the header line when the columns differ from the last one written."""
        if columns != self._columns:
            self._writer.writerow(columns)
            self._columns = columns

    def write(self, msg) -> None:
        """One line for a message; one line per point for a PointCloud2."""
        if isinstance(msg, PointCloud2):
            self._write_cloud(msg)
            return
        if is_assignment_message(msg):
            self._write_assignment(msg)
            return
        flat = flatten_message(msg, self._max_array_length)
        self._header(list(flat))
        self._writer.writerow([format_cell(v) for v in flat.values()])

    def _write_cloud(self, msg: PointCloud2) -> None:
        """One line per point (up to max_rows), led by the cloud's stamp, frame and point index."""
        try:
            names, columns = table_columns(pointcloud_to_array(msg))
        except ValueError as exc:
            print(f'echo: skipping a PointCloud2 that cannot be decoded: {exc}', file=sys.stderr)
            return
        self._header(
            ['header.stamp.sec', 'header.stamp.nanosec', 'header.frame_id', 'point'] + names
        )
        stamp = msg.header.stamp
        count = len(columns[0]) if columns else 0
        shown = count if self._max_rows is None else min(count, self._max_rows)
        for row in range(shown):
            self._writer.writerow(
                [stamp.sec, stamp.nanosec, msg.header.frame_id, row]
                + [format_cell(column[row]) for column in columns]
            )

    def _write_assignment(self, msg) -> None:
        """One line per (part, camera) of a /memo/camera_assignment message, led by its stamp."""
        rows = assignment_rows(msg)
        self._header(['header.stamp.sec', 'header.stamp.nanosec', 'mode'] + list(rows[0]))
        mode = next(kv.value for kv in msg.status[0].values if kv.key == 'mode')
        for row in rows:
            self._writer.writerow(
                [msg.header.stamp.sec, msg.header.stamp.nanosec, mode]
                + [format_cell(v) for v in row.values()]
            )


class YamlPrinter:
    """Writes messages as YAML documents separated by '---'."""

    def __init__(self, out: TextIO, truncate_length: int | None, max_rows: int | None) -> None:
        self._out = out
        self._truncate_length = truncate_length
        self._max_rows = max_rows

    def write(self, msg) -> None:
        """One YAML document and its '---' separator."""
        if (
            is_assignment_message(msg) and self._truncate_length is not None
        ):  # its part x camera table; --full: raw
            self._out.write('\n'.join(assignment_table(msg)) + '\n---\n')
            return
        self._out.write(message_to_yaml(msg, self._truncate_length, self._max_rows) + '---\n')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Return the topic, optional type, and output and QoS options."""
    parser.add_argument('topic', help='topic to print')
    parser.add_argument(
        'type', nargs='?', help='message type (pkg/msg/Name); default: from the graph'
    )
    parser.add_argument('--once', action='store_true', help='print one message, then exit')
    parser.add_argument('--count', type=int, metavar='N', help='print N messages, then exit')
    parser.add_argument(
        '--timeout',
        type=float,
        metavar='SECONDS',
        help='fail when no message arrives within this long; with --count, also when the next '
        'one does not; without, stop quietly once messages stop for this long',
    )
    parser.add_argument(
        '--csv',
        action='store_true',
        help='CSV: a header line, then one line per message (per point for a PointCloud2)',
    )
    parser.add_argument(
        '--full', action='store_true', help='print long arrays (image and cloud data) in full'
    )
    parser.add_argument(
        '--truncate-length',
        type=int,
        default=DEFAULT_TRUNCATE,
        metavar='N',
        help=f'abbreviate numeric arrays longer than N (default {DEFAULT_TRUNCATE})',
    )
    parser.add_argument(
        '--max-rows',
        type=int,
        metavar='N',
        help=f'points of a PointCloud2 to show (default {YAML_MAX_ROWS} in YAML, all in CSV; '
        '0: no table in YAML)',
    )
    parser.add_argument(
        '--qos',
        choices=['auto'] + sorted(RELIABILITY),
        default='auto',
        help='subscription reliability (auto: reliable when every publisher is)',
    )
    parser.add_argument(
        '--qos-depth', type=int, default=10, help='subscription history depth (default 10)'
    )


def _check(args: argparse.Namespace) -> int | None:
    """Return the number of messages to print (None: forever), after validating the options."""
    from memo_ros.tools.cli import CliError

    if args.count is not None and args.count < 1:
        raise CliError('--count must be at least 1')
    if args.timeout is not None and args.timeout <= 0:
        raise CliError('--timeout must be positive')
    if args.max_rows is not None and args.max_rows < 0:
        raise CliError('--max-rows must not be negative')
    if args.truncate_length < 0 or args.qos_depth < 1:
        raise CliError('--truncate-length must not be negative and --qos-depth must be at least 1')
    return 1 if args.once else args.count


def _printer(args: argparse.Namespace):
    """Return the CSV or YAML printer the options ask for."""
    truncate = None if args.full else args.truncate_length
    if args.csv:
        return CsvPrinter(sys.stdout, truncate, args.max_rows)
    return YamlPrinter(
        sys.stdout, truncate, YAML_MAX_ROWS if args.max_rows is None else args.max_rows
    )


def run(args: argparse.Namespace) -> int:
    """Subscribe to the topic and print messages until the count is reached, a timeout.

    Or a signal.
    """
    from memo_ros.tools.cli import CliError

    wanted = _check(args)
    topic = absolute_topic(args.topic)
    printer = _printer(args)
    start = time.monotonic()
    with ros_session('memo_ros_echo') as (node, executor), stop_on_signals() as stop:
        msgtype = args.type or wait_for_topic_type(node, topic, args.timeout, stop)
        if msgtype is None:
            if stop.is_set():
                return 0
            raise CliError(f'topic {topic} did not appear within {args.timeout:g} s')
        try:
            msg_class = import_message_type(msgtype)
        except MessageTypeError as exc:
            raise CliError(str(exc)) from None
        pending: deque = deque()
        qos = adapted_qos(node, topic, args.qos_depth, args.qos, 'auto')
        node.create_subscription(msg_class, topic, lambda msg: pending.append(msg), qos)
        printed = 0
        last = start
        while not stop.is_set() and (wanted is None or printed < wanted):
            executor.spin_once(timeout_sec=0.1)
            while pending and (wanted is None or printed < wanted):
                _print(printer, pending.popleft())
                printed += 1
                last = time.monotonic()
            if (
                args.timeout is not None
                and time.monotonic() - last > args.timeout
                and not stop.is_set()
            ):
                if printed == 0:
                    raise CliError(f'no message on {topic} within {args.timeout:g} s')
                if wanted is None:
                    break
                raise CliError(
                    f'no further message on {topic} within {args.timeout:g} s '
                    f'({printed} of {wanted} printed)'
                )
    return 0


def _print(printer, msg) -> None:
    """Print one message; stop quietly when stdout is closed (e.g. piped into head)."""
    try:
        printer.write(msg)
        sys.stdout.flush()
    except BrokenPipeError:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        raise SystemExit(0) from None
