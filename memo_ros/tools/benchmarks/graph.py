"""Latency and throughput of the whole live graph fed a studio bag at fixed rates.

``benchmark graph``.

A studio-arm bag (640x480 mono8; 3 cameras, or 4 with ``--rig ring4``) is simulated once into a
temporary directory (or given with ``--bag``).  For each rate a fresh graph is started as users
start it, ``memo-ros launch STUDIO`` (one contour_node per camera, selector_node, tracker_node,
each its own process), with best-effort images as from live cameras.  This process plays the bag's
``/<cam>/image_raw`` (best effort) and ``/<cam>/camera_info`` (reliable) with :class:`BagPlayer`
at the rate (with a Fast DDS shared-memory segment large enough for all cameras, see
memo_ros.ros.dds.player_segment), and restamps every frame to the wall clock at the moment its
first message goes out (all messages of a frame share the stamp).  Every output carries its
frame's stamp, so a stage's cumulative latency is the output's publication time (its DDS source
timestamp) minus the stamp: ``/<cam>/contours``,
``/memo/camera_assignment``, ``/memo/joint_states`` (end to end) and ``/memo/processed`` (every
frame the tracker finished, with its outcome).  The first frames (the empty studio the contour
nodes learn their background from, and the tracker's start) are warm-up and left out of the
statistics; CPU is measured over the timed frames from /proc, peak RSS is each process's VmHWM.
Frames without joint_states are counted by reason, and the nodes' own drop counters come from
``/diagnostics``.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
import tempfile
import threading
import time

import numpy as np

from memo_ros.core.simulation.scenarios import RIGS
from memo_ros.tools.benchmarks.graph_figures import SETTLE, rate_figures
from memo_ros.tools.benchmarks.graph_probe import FrameTrace, Probe, Restamper
from memo_ros.tools.benchmarks.graph_processes import (
    GRAPH_TIMEOUT,
    RSS_PERIOD,
    cpu_snapshot,
    memory_growth,
    peak_rss_of,
    rss_of,
    start_graph,
    stop_graph,
    wait_for_nodes,
)
from memo_ros.tools.proc_stats import (
    log_tail,
)

SCENARIO = 'studio-arm'


SIZE = (640, 480)


FRAMES = 330  # subject frames simulated; the studio adds its empty frames before them


WARMUP = 40  # first frames of the bag left out of the statistics (10 empty + 30 tracked)


RATES = (30.0, 60.0)


DEFAULT_DOMAIN_ID = 78


DRAIN_IDLE = 10.0  # s without any output after playback: the graph is done (a re-initialisation


# from the silhouettes can keep the tracker quiet for seconds)
DRAIN_TIMEOUT = 60.0


DIAGNOSTICS_WAIT = 3.0  # s for every node's diagnostics after the drain (they come once a second)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Return the graph suite's options (on the benchmark command's parser)."""
    parser.add_argument(
        '--rates',
        default=','.join(f'{r:g}' for r in RATES),
        help='graph: input frame rates, Hz, comma separated (default 30,60)',
    )
    parser.add_argument(
        '--frames',
        type=int,
        help=f'graph: subject frames of the simulated bag (default {FRAMES}; the studio adds '
        'its empty frames before them); dance: the first frames of the dance (default all)',
    )
    parser.add_argument(
        '--warmup',
        type=int,
        default=WARMUP,
        help=f'graph: first frames of the bag left out of the statistics (default {WARMUP})',
    )
    parser.add_argument(
        '--bag',
        type=Path,
        help='graph: play this bag (studio YAML beside it as BAG.yaml) instead of simulating one',
    )
    parser.add_argument(
        '--loops',
        type=int,
        default=1,
        help='graph: play the bag this many times in a row, stamps going on (a soak; default 1)',
    )
    parser.add_argument('--out', type=Path, help='also write the report as JSON to this file')


def command_words(args: argparse.Namespace) -> list[str]:
    """Return this suite's options as command-line words (for the report's command line)."""
    words = ['--rates', args.rates, '--warmup', str(args.warmup)] + (
        ['--loops', str(args.loops)] if args.loops > 1 else []
    )
    frames = FRAMES if args.frames is None else args.frames
    if args.bag:
        return words + ['--bag', str(args.bag)]
    return words + ['--frames', str(frames), '--rig', graph_rig(args)]


def graph_rig(args: argparse.Namespace) -> str:
    """Return the simulated bag's rig: ``--rig``, or the orthogonal studio."""
    return RIGS[0] if args.rig is None else args.rig


def parse_rates(text: str) -> list[float]:
    """'30,60' -> [30.0, 60.0]; ValueError for anything not a list of positive numbers."""
    rates = [float(word) for word in text.split(',') if word.strip()]
    if not rates or any(not np.isfinite(r) or r <= 0 for r in rates):
        raise ValueError(f'rates must be positive numbers, not {text!r}')
    return rates


def measure(args: argparse.Namespace) -> dict:
    """Return the suite's figures for ``memo-ros benchmark graph`` (user errors as CliError)."""
    from memo_ros.tools.cli import CliError

    try:
        rates = parse_rates(args.rates)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    frames = FRAMES if args.frames is None else args.frames
    if frames < 1 or args.warmup < 0 or args.loops < 1:
        raise CliError('--frames and --loops must be at least 1 and --warmup not negative')
    if args.bag is not None:
        if args.rig is not None:
            raise CliError("--rig chooses the simulated bag's cameras; a --bag has its own")
        studio = args.bag.with_name(args.bag.name + '.yaml')
        if not args.bag.exists() or not studio.is_file():
            raise CliError(f'need the bag {args.bag} and its studio file {studio}')
    rig = graph_rig(args)
    if rig not in RIGS:
        raise CliError(f'unknown rig {rig!r} for the graph; known: {", ".join(RIGS)}')
    return run_graph_benchmark(rates, frames, args.warmup, args.bag, loops=args.loops, rig=rig)


def run_rate(
    bag: Path,
    studio_file: Path,
    cameras: list[str],
    expected_nodes: int,
    rate_hz: float,
    bag_hz: float,
    warmup: int,
    domain_id: int,
    env: dict,
    log: Path,
    loops: int = 1,
) -> dict:
    """Launch a fresh graph, play the bag into it ``loops`` times at ``rate_hz`` frames/s.

    And measure it.
    """
    from memo_ros.ros.dds import ros_session
    from memo_ros.tools.bag.play import BagPlayer, PlayOptions
    from memo_ros.tools.cli import CliError

    launch = start_graph(studio_file, env, log)
    nodes: dict[int, str] = {}
    try:
        nodes = wait_for_nodes(launch, expected_nodes, log)
        pids = {**nodes, launch.pid: 'launcher', os.getpid(): 'benchmark (player, probe)'}
        window: dict[str, tuple] = {}

        def on_frame(trace: FrameTrace) -> None:
            if trace.index == warmup:
                window['start'] = cpu_snapshot(pids)

        def on_processed(trace: FrameTrace) -> None:
            if trace.index >= warmup:
                window['end'] = cpu_snapshot(pids)

        restamper = Restamper(on_frame)
        rss_samples: list[
            tuple[int, dict[int, float | None]]
        ] = []  # (frames published, pid -> MB)
        with ros_session('memo_graph_benchmark', domain_id) as (node, executor):
            probe = Probe(node, cameras, restamper.frames, on_processed)
            selector = any(label == 'selector_node' for label in nodes.values())
            options = {'rate': rate_hz / bag_hz, 'wait_timeout': GRAPH_TIMEOUT}
            players = [
                BagPlayer(
                    node,
                    bag,
                    PlayOptions(
                        topics=[f'/{c}/image_raw' for c in cameras],
                        reliability='best_effort',
                        wait_for_subscribers=1,
                        **options,
                    ),
                    before_publish=restamper.before_publish,
                ),
                BagPlayer(
                    node,
                    bag,
                    PlayOptions(
                        topics=[f'/{c}/camera_info' for c in cameras],
                        reliability='reliable',
                        wait_for_subscribers=2 if selector else 1,
                        **options,
                    ),
                    before_publish=restamper.before_publish,
                ),
            ]
            try:
                _wait_for_graph(node, executor, players, probe, set(nodes.values()), launch, log)
                window['idle'] = _settle(executor, pids)
                stop = threading.Event()
                threads = [
                    threading.Thread(target=_play_passes, args=(p, stop, loops), daemon=True)
                    for p in players
                ]
                for thread in threads:
                    thread.start()
                try:
                    next_sample = 0.0
                    while any(thread.is_alive() for thread in threads):
                        executor.spin_once(timeout_sec=0.02)
                        if (
                            time.monotonic() >= next_sample
                        ):  # memory over the run (a soak's growth)
                            rss_samples.append((len(restamper.frames), rss_of(pids)))
                            next_sample = time.monotonic() + RSS_PERIOD
                finally:
                    stop.set()
                    for thread in threads:
                        thread.join()
                _drain(executor, probe, restamper)
                drained = time.monotonic()
                window.setdefault('end', cpu_snapshot(pids))
                deadline = drained + DIAGNOSTICS_WAIT
                while time.monotonic() < deadline and any(
                    probe.diagnostics.get(n, {}).get('time', 0.0) < drained for n in nodes.values()
                ):
                    executor.spin_once(timeout_sec=0.05)
                peak_rss = {pid: peak_rss_of(pid) for pid in pids}
                rss_samples.append((len(restamper.frames), rss_of(pids)))
                if launch.poll() is not None:
                    raise CliError(f'the graph stopped during the benchmark: {log_tail(log)}')
            finally:
                for player in players:
                    player.close()
    finally:
        stop_graph(launch, nodes)
    result = rate_figures(rate_hz, cameras, warmup, restamper, probe, pids, window, peak_rss)
    result['loops'] = loops
    result['memory'] = memory_growth(pids, rss_samples, warmup)
    return result


def _play_passes(player, stop: threading.Event, passes: int) -> None:
    """Play the bag ``passes`` times in a row (the Restamper sees it start again and stamps on)."""
    for _ in range(passes):
        if stop.is_set() or player.play_once(stop) == 0:
            break


def _wait_for_graph(
    node, executor, players, probe: Probe, labels: set[str], launch, log: Path
) -> None:
    """Until the players' topics have their subscribers, the probe its publishers.

    And every node reported.
    """
    from memo_ros.tools.cli import CliError

    deadline = time.monotonic() + GRAPH_TIMEOUT
    while True:
        missing = [t for p in players for t in p.unmatched_topics()]
        missing += [t for t in probe.topics if node.count_publishers(t) < 1]
        missing += [f'{n} diagnostics' for n in sorted(labels - set(probe.diagnostics))]
        if not missing:
            break
        if launch.poll() is not None:
            raise CliError(f'the graph stopped before it was up: {log_tail(log)}')
        if time.monotonic() > deadline:
            raise CliError(
                f'the graph did not come up within {GRAPH_TIMEOUT:g} s; missing: '
                f'{", ".join(missing)}'
            )
        executor.spin_once(timeout_sec=0.05)


def _settle(executor, pids: dict[int, str]) -> tuple:
    """Spin SETTLE s with the graph up and idle; return the CPU snapshots before and after.

    Their difference is the idle CPU.
    """
    before = cpu_snapshot(pids)
    settle = time.monotonic() + SETTLE
    while time.monotonic() < settle:
        executor.spin_once(timeout_sec=0.05)
    return before, cpu_snapshot(pids)


def _drain(executor, probe: Probe, restamper: Restamper) -> None:
    """Spin until the tracker finished the last frame, or no output came for DRAIN_IDLE s.

    The tracker reports every frame it heard of, in order or skipped; a quiet DRAIN_IDLE s means
    frames it never heard of. At most DRAIN_TIMEOUT s.
    """
    last = max(restamper.frames.values(), key=lambda t: t.index, default=None)
    deadline = time.monotonic() + DRAIN_TIMEOUT
    probe.last_output = time.monotonic()
    while time.monotonic() < deadline and time.monotonic() - probe.last_output < DRAIN_IDLE:
        if last is not None and last.processed is not None:
            break
        executor.spin_once(timeout_sec=0.05)


def _recorded_rate(bag: Path, camera: str, default_hz: float) -> tuple[int, float]:
    """Return the images of ``camera`` in ``bag`` and the rate they were recorded at."""
    from memo_ros.tools.bag.info import bag_summary

    summary = bag_summary(bag)
    images = {t.topic: t.count for t in summary.topics}.get(f'/{camera}/image_raw', 0)
    seconds = summary.duration_ns * 1e-9
    return images, (images - 1) / seconds if images > 1 and seconds > 0 else default_hz


def run_graph_benchmark(
    rates=RATES,
    frames: int = FRAMES,
    warmup: int = WARMUP,
    bag: Path | None = None,
    domain_id: int | None = None,
    loops: int = 1,
    rig: str = RIGS[0],
) -> dict:
    """Simulate the bag once (unless given), then run a fresh graph at every rate; the report.

    ``rig`` (:data:`RIGS`) is the simulated studio's cameras.
    """
    from memo_ros.core.formats.studio import Studio
    from memo_ros.core.simulation.imaging import ImagingOptions
    from memo_ros.ros.dds import player_segment, player_segment_bytes
    from memo_ros.tools.launch import graph_commands
    from memo_ros.tools.simulate import simulate

    if domain_id is None:
        domain_id = int(os.environ.get('ROS_DOMAIN_ID') or DEFAULT_DOMAIN_ID)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'  # this process's participant too
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id), PYTHONUNBUFFERED='1')
    with tempfile.TemporaryDirectory(prefix='memo_ros_bench_graph_') as tmp:
        simulated = bag is None
        # a simulated bag is rendered at the rate it is played, so the person moves as fast as
        # before a camera of that rate (a 30 Hz bag played at 90 Hz moves three times as fast)
        bags = [
            simulate(
                SCENARIO,
                Path(tmp) / f'bag_{k}',
                frames=frames,
                frame_rate=rate,
                width=SIZE[0],
                height=SIZE[1],
                options=ImagingOptions(),
                rig=rig,
            ).bag
            if simulated
            else bag
            for k, rate in enumerate(rates)
        ]
        studio_files = [b.with_name(b.name + '.yaml') for b in bags]
        studio = Studio.load(studio_files[0])
        cameras = studio.camera_names
        segment = player_segment_bytes(studio.cameras)
        expected = len(graph_commands(studio, studio_files[0]))
        # a bag of your own is read once, however many rates play it
        rate_of = {b: _recorded_rate(b, cameras[0], studio.frame_rate) for b in set(bags)}
        recorded = [rate_of[b] for b in bags]
        images, bag_hz = recorded[0]
        # only for this process's participants: the nodes got ``env`` from before
        with player_segment(segment, tmp, localhost_only=True) as own_profile:
            rows = [
                run_rate(
                    bags[k],
                    studio_files[k],
                    cameras,
                    expected,
                    rate,
                    recorded[k][1],
                    warmup,
                    domain_id,
                    env,
                    Path(tmp) / f'graph_{k}.log',
                    loops,
                )
                for k, rate in enumerate(rates)
            ]
            for row, (_, hz) in zip(rows, recorded):
                row['bag_hz'] = hz
        first = cameras[0]
        size = next((f'{c.width}x{c.height}' for c in studio.cameras if c.name == first), '?')
    return {
        'cpus': len(os.sched_getaffinity(0)),
        'bag': 'simulated' if simulated else str(bag),
        'scenario': f'{SCENARIO}, {rig} rig' if simulated else studio.name,
        'cameras': cameras,
        'size': size,
        'bag_frames': images,
        'bag_hz': bag_hz,
        'images': 'best_effort',
        'player_shm_segment_mb': segment / 2**20 if own_profile else None,
        'warmup_frames': warmup,
        'domain_id': domain_id,
        'rates': rows,
    }
