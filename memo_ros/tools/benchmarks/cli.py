"""`memo-ros benchmark SUITE`: run one suite, print its figures with the command that made them."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import shlex

from memo_ros.tools.benchmarks import dance as bench_dance
from memo_ros.tools.benchmarks import graph as bench_graph
from memo_ros.tools.benchmarks.foundation import (
    print_report,
    renderer_times,
    simulator_throughput,
)
from memo_ros.tools.benchmarks.graph_figures import print_graph_benchmark
from memo_ros.tools.benchmarks.report import machine, with_command

SUITES = (
    'foundation',
    'contours',
    'contour-node',
    'selector',
    'tracker',
    'walker',
    'graph',
    'dance',
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare this command's arguments and options."""
    parser.add_argument(
        'suite',
        choices=SUITES,
        help='what to measure: foundation = renderer and simulator; '
        'contours = the contour pipeline per 640x480 frame, one OpenCV thread, with and '
        'without edge lines; '
        'contour-node = the contour_node process fed at 30 and 60 Hz over DDS; '
        'selector = camera assignment per frame, 14 parts x 3 cameras (--repeat: passes over '
        'each sequence); tracker = the articulated EKF update per frame at 200, 1,000 and '
        "5,000 contour points per camera from the studio's 3 cameras, and at 1,000 from each "
        'count of --cameras on a ring, with the cost per added camera '
        "(--repeat: passes over the sequence); walker = Rohr's "
        'walker per '
        "frame on a street-walk, initialization and tracking, against the paper's exhaustive grid "
        '(--repeat: passes over the sequence); graph = the whole live graph (3 contour nodes, '
        'selector, tracker) fed a 3-camera 640x480 bag at 30 and 60 Hz: latency per stage and end '
        'to end, rates, drops, CPU and memory per process; dance = the articulated tracker on '
        'studio-dance from 8 headings on the orthogonal and the ring4 rig against issue 16: '
        'MPJPE, heading error after 1 s, side swaps, limb exchanges per run (--headings, --rig, '
        '--frames, --size, --contours, --jobs)',
    )
    parser.add_argument(
        '--repeat', type=int, default=20, help='timed repetitions per renderer case (default 20)'
    )
    parser.add_argument(
        '--json', action='store_true', help='print one JSON object instead of the table'
    )
    parser.add_argument(
        '--cameras',
        default='3,4,6,8',
        help='tracker: camera counts on a ring around the studio, 1,000 contour points each, '
        'comma separated (default 3,4,6,8)',
    )
    bench_graph.add_arguments(parser)
    bench_dance.add_arguments(parser)


def run(args: argparse.Namespace) -> int:
    """Run the command with parsed ``args``; return its exit code."""
    from memo_ros.tools.cli import CliError

    if args.repeat < 1:
        raise CliError('--repeat must be at least 1')
    measure, show = _suite(args.suite)
    report = {'command': command_line(args), 'machine': machine(), **measure(args)}
    if args.out:
        Path(args.out).write_text(json.dumps(report, indent=1) + '\n')
    if args.json:
        print(json.dumps(report))
    else:
        show(report)
    return 0


def _suite(name: str):
    """Return (measure(args) -> dict, print(report)) of a benchmark suite.

    The node suites are imported lazily.
    """
    if name == 'contours':
        from memo_ros.tools.benchmarks.contours import (
            print_contour_benchmark,
            run_contour_benchmark,
        )

        return (lambda args: run_contour_benchmark(repeat=args.repeat)), with_command(
            print_contour_benchmark
        )
    if name == 'selector':
        from memo_ros.tools.benchmarks.selector import (
            print_selector_benchmark,
            run_selector_benchmark,
        )

        return (lambda args: run_selector_benchmark(repeat=args.repeat)), with_command(
            print_selector_benchmark
        )
    if name == 'tracker':
        from memo_ros.tools.benchmarks.tracker import (
            parse_cameras,
            print_tracker_benchmark,
            run_tracker_benchmark,
        )

        def measure_tracker(args: argparse.Namespace) -> dict:
            from memo_ros.core.multiview.tracking import TrackerSettings
            from memo_ros.tools.cli import CliError

            try:
                cameras = parse_cameras(args.cameras)
            except ValueError as exc:
                raise CliError(str(exc)) from None
            overrides = bench_dance.tracker_overrides(args.tracker)
            return run_tracker_benchmark(
                repeat=args.repeat, settings=TrackerSettings(**overrides), cameras=cameras
            ) | {'tracker': overrides}

        return measure_tracker, with_command(print_tracker_benchmark)
    if name == 'walker':
        from memo_ros.tools.benchmarks.walker import (
            print_walker_benchmark,
            run_walker_benchmark,
        )

        return (lambda args: run_walker_benchmark(repeat=args.repeat)), with_command(
            print_walker_benchmark
        )
    if name == 'graph':
        return bench_graph.measure, with_command(print_graph_benchmark)
    if name == 'dance':
        return bench_dance.measure, with_command(bench_dance.print_dance_benchmark)
    if name == 'contour-node':
        from memo_ros.tools.benchmarks.contour_node import (
            print_node_benchmark,
            run_node_benchmark,
        )

        return (lambda args: run_node_benchmark()), with_command(print_node_benchmark)
    return (
        lambda args: {
            'renderer': renderer_times(args.repeat),
            'simulator': simulator_throughput(),
        },
        print_report,
    )


def command_line(args: argparse.Namespace) -> str:
    """Return the command line that reproduces this run."""
    if args.suite == 'graph':
        options = bench_graph.command_words(args)
    elif args.suite == 'dance':
        options = bench_dance.command_words(args)
    else:
        options = (
            [] if args.suite == 'contour-node' else ['--repeat', str(args.repeat)]
        )  # that suite has no repeats
        if args.suite == 'tracker':
            options += ['--cameras', args.cameras]
            for setting in args.tracker:
                options += ['--tracker', setting]
    words = ['memo-ros', 'benchmark', args.suite, *options] + (['--json'] if args.json else [])
    return shlex.join(words)
