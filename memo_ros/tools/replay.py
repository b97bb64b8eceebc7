"""Replay a bag through the live graph.

Launch it, play the cameras into it, record what it publishes.

``memo-ros replay BAG --out OUT`` starts ``memo-ros launch STUDIO --reliable-images`` (the studio
defaults to ``BAG.yaml``, as the simulator writes it), plays the bag's image and camera_info topics
over DDS and records every output topic to the mcap bag OUT.  With ``--rate 0`` (the default)
playback is paced by the graph itself: before frame t+1 goes out, the player waits until the
tracker said frame t is done on ``/memo/processed``, as long as the tracker shows it is working
(a frame on its /diagnostics, ``working_on``, or an outcome within ``--frame-timeout``; at most
MAX_FRAME_WAIT_S), so the result depends neither on the machine's load nor on how long a start
takes.  ``--rate R`` plays with the recorded timing instead.  It exits when the input is
exhausted and the graph has drained; the node logs go to OUT.log.
"""

from __future__ import annotations

import argparse
from contextlib import contextmanager
from pathlib import Path
import struct
import subprocess
import sys
import tempfile
import threading
import time
from typing import Iterator

from memo_ros.core.formats.studio import Studio
from memo_ros.tools.proc_stats import stop_process

OUTPUT_TOPICS = (
    '/memo/joint_states',
    '/memo/body_poses',
    '/memo/markers',
    '/memo/root_pose',
    '/memo/camera_assignment',
    '/memo/walker/measurement',
    '/memo/processed',
    '/diagnostics',
)
INPUT_SUFFIXES = ('/image_raw', '/camera_info')
GRAPH_TIMEOUT_S = 60.0
MATCH_TIMEOUT_S = 10.0  # for the nodes' side of the matches, once the player's and recorder's
DRAIN_IDLE_S = 2.0
LAUNCH_STOP_S = 15.0  # for the launched graph to stop on SIGINT before it is killed


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare this command's arguments and options."""
    parser.add_argument(
        'bag', type=Path, help='input bag with /<cam>/image_raw and /<cam>/camera_info'
    )
    parser.add_argument(
        '--studio', type=Path, help='studio YAML (default: BAG.yaml beside the bag)'
    )
    parser.add_argument(
        '--out', '-o', type=Path, required=True, help='output bag directory (must not exist)'
    )
    parser.add_argument(
        '--rate',
        type=float,
        default=0.0,
        help='0 (default): paced by the graph (back-pressure); R > 0: recorded timing x R',
    )
    parser.add_argument(
        '--no-launch',
        action='store_true',
        help='play into a graph that is already running (started with `memo-ros launch STUDIO '
        '--reliable-images`, here or on other hosts) instead of launching one',
    )
    parser.add_argument(
        '--frame-timeout',
        type=float,
        default=2.0,
        help='with back-pressure, how long the tracker may show no work (no frame done, no '
        'working_on on its diagnostics) before the next frame goes out, s (default 2)',
    )
    parser.add_argument(
        '--record-contours',
        action='store_true',
        help="also record every camera's /<cam>/contours (to re-run the tracker offline)",
    )


def run(args: argparse.Namespace) -> int:
    """Run the command with parsed ``args``; return its exit code."""
    from memo_ros.tools.cli import CliError

    studio_file = args.studio or args.bag.with_name(args.bag.name + '.yaml')
    if not args.bag.exists():
        raise CliError(f'no bag at {args.bag}')
    if not studio_file.is_file():
        raise CliError(f'no studio file at {studio_file} (give --studio)')
    if args.out.exists():
        raise CliError(f'{args.out} exists already')
    if args.rate < 0 or args.frame_timeout <= 0:
        raise CliError('--rate must not be negative and --frame-timeout must be positive')
    cameras = Studio.load(studio_file).camera_names
    missing = [
        t
        for t in (f'/{c}{s}' for c in cameras for s in INPUT_SUFFIXES)
        if t not in _bag_topics(args.bag)
    ]
    if missing:
        raise CliError(f"{args.bag} lacks the studio's camera topics {', '.join(missing)}")
    extra = [f'/{c}/contours' for c in cameras] if args.record_contours else []
    report = replay(
        args.bag,
        studio_file,
        args.out,
        cameras,
        args.rate,
        args.frame_timeout,
        not args.no_launch,
        extra,
    )
    print(
        f'replayed   {report["frames"]} frames of {args.bag} in {report["seconds"]:.1f} s '
        f'({report["frames"] / max(report["seconds"], 1e-9):.1f} frames/s)'
    )
    print(
        f'processed  {report["processed"]} frames reported done by the graph, '
        f'{report["timeouts"]} waits timed out'
    )
    print(
        f'recorded   {args.out}: '
        + ', '.join(f'{t} {n}' for t, n in sorted(report['recorded'].items()))
    )
    print(f'node logs  {report["log"]}')
    return 0 if report['graph_ok'] else 1


def _bag_topics(bag: Path) -> dict[str, str]:
    """Return the bag's topics, read before anything is launched.

    An unreadable bag is a one-line error.
    """
    from memo_ros.ros.bagio import BagError, bag_topics
    from memo_ros.tools.cli import CliError

    try:
        return bag_topics(bag)
    except BagError as exc:
        raise CliError(str(exc)) from None


def frame_stamp(data: bytes) -> int:
    """Header stamp (ns) of a CDR message whose first field is a std_msgs/Header.

    Image, CameraInfo.
    """
    sec, nanosec = struct.unpack_from('<iI', data, 4)  # after the 4-byte encapsulation header
    return sec * 1_000_000_000 + nanosec


MAX_FRAME_WAIT_S = 120.0  # longest wait for one frame, however long the tracker says it works


class Pacer:
    """Back-pressure.

    Before a new frame goes out, wait until the graph said the previous one is done: while the
    tracker says on /diagnostics (once a second) that it is working on a frame, a start that
    takes seconds (the heading search, the body's height) is waited for, so the next frames are
    not segmented before the tracked body they wait for exists; a tracker idle, killed or
    restarted (the frame lost with it) for ``timeout`` is not.
    """

    def __init__(self, timeout: float) -> None:
        self.timeout = timeout
        self.done_ns = -1
        self.current_ns: int | None = None
        self.frames = 0
        self.processed = 0
        self.timeouts = 0
        self.alive = time.monotonic()  # when the tracker last showed it works on a frame
        self._cond = threading.Condition()

    def on_processed(self, msg) -> None:
        """Note that the graph finished the frame of this /memo/processed message."""
        stamp = msg.stamp.sec * 1_000_000_000 + msg.stamp.nanosec
        with self._cond:
            self.processed += 1
            self.done_ns = max(self.done_ns, stamp)
            self.alive = time.monotonic()
            self._cond.notify_all()

    def on_diagnostics(self, msg) -> None:
        """Note a tracker that reports it is working on a frame (``working_on``)."""
        busy = any(
            kv.key == 'working_on' and kv.value for status in msg.status for kv in status.values
        )
        if busy:
            with self._cond:
                self.alive = time.monotonic()

    def before_publish(self, item, pace: bool) -> None:
        """Hold a frame back until the previous one was processed (with back-pressure)."""
        stamp = frame_stamp(item.data)
        if self.current_ns is not None and stamp <= self.current_ns:
            return
        if pace and self.current_ns is not None:
            self.wait_done()
        self.current_ns = stamp
        self.frames += 1

    def wait_done(self) -> None:
        """Wait for the current frame while the tracker works on one; count a wait that gave up."""
        start = time.monotonic()
        with self._cond:
            self.alive = max(self.alive, start)
            while self.done_ns < self.current_ns:
                now = time.monotonic()
                if now - self.alive > self.timeout or now - start > MAX_FRAME_WAIT_S:
                    self.timeouts += 1
                    return
                self._cond.wait(min(self.timeout, 0.1))


def replay(
    bag: Path,
    studio_file: Path,
    out: Path,
    cameras: list[str],
    rate: float = 0.0,
    frame_timeout: float = 2.0,
    launch_graph: bool = True,
    extra_topics: list[str] | None = None,
) -> dict:
    """Launch the graph for ``studio_file`` (unless it runs already), play ``bag`` into it.

    Record its outputs to ``out``; a report.
    """
    from diagnostic_msgs.msg import DiagnosticArray
    from std_msgs.msg import Header

    from memo_ros.ros.dds import (
        MatchedOnDiagnostics,
        player_segment,
        player_segment_bytes,
        ros_session,
    )
    from memo_ros.tools.bag.play import BagPlayer, PlayOptions
    from memo_ros.tools.bag.record import BagRecorder, RecordOptions
    from memo_ros.tools.progress import Progress

    log_path = out.with_name(out.name + '.log')
    out.parent.mkdir(parents=True, exist_ok=True)
    inputs = [f'/{c}{s}' for c in cameras for s in INPUT_SUFFIXES]
    pacer = Pacer(frame_timeout)
    segment = player_segment_bytes(Studio.load(studio_file).cameras)
    # the graph stops after the session has closed (the with's items exit last to first): a
    # participant that destroys its entities while the graph's leave can deadlock in Fast DDS
    # 2.14 (the discovery thread holds the PDP lock and waits for the event thread, which waits
    # for that lock; seen once in ~25 replays, memo-ros replay then hung at exit for good)
    with (
        tempfile.TemporaryDirectory(prefix='memo_replay_') as tmp,
        player_segment(segment, tmp),
        open(log_path, 'w', encoding='utf-8') as log,
        _launched(studio_file, log, launch_graph) as launch,
        ros_session('memo_replay') as (node, executor),
    ):
        stop = threading.Event()
        spinner = threading.Thread(target=lambda: _spin(executor, stop, recorder), daemon=True)
        try:
            node.create_subscription(Header, '/memo/processed', pacer.on_processed, 100)
            node.create_subscription(DiagnosticArray, '/diagnostics', pacer.on_diagnostics, 100)
            matched = MatchedOnDiagnostics(node)
            recorder = BagRecorder(
                node, out, RecordOptions(topics=[*OUTPUT_TOPICS, *(extra_topics or [])])
            )
            spinner.start()
            player = BagPlayer(
                node,
                bag,
                PlayOptions(
                    rate=rate, topics=inputs, wait_for_subscribers=1, wait_timeout=GRAPH_TIMEOUT_S
                ),
                before_publish=lambda item: pacer.before_publish(item, rate == 0),
            )
            _wait_for_graph(node, recorder, player, launch)
            _wait_for_nodes_side(node, matched, recorder, player)
            start = time.monotonic()
            total = sum(1 for _ in player._messages())
            progress = Progress(total, 'replay', sys.stderr.isatty())
            player.after_publish = lambda item: progress.update(item.index + 1)
            player.play()
            player.flush()
            progress.close()
            if rate == 0 and pacer.current_ns is not None:  # the last frame
                pacer.wait_done()
            _drain(recorder)
            seconds = time.monotonic() - start
            recorded = dict(recorder.counts)
            graph_ok = launch is None or launch.poll() is None
            _stop_spinner(stop, spinner)  # before the player's and recorder's entities go
            player.close()
            recorder.close()
        finally:
            _stop_spinner(stop, spinner)  # no spin may run while the session shuts down
    return {
        'frames': pacer.frames,
        'processed': pacer.processed,
        'timeouts': pacer.timeouts,
        'seconds': seconds,
        'recorded': recorded,
        'log': str(log_path),
        'graph_ok': graph_ok,
    }


@contextmanager
def _launched(studio_file: Path, log, launch_graph: bool) -> Iterator[subprocess.Popen | None]:
    """Run the graph for ``studio_file`` (if ``launch_graph``) and stop it on exit."""
    launch = (
        subprocess.Popen(
            [
                sys.executable,
                '-m',
                'memo_ros.tools.cli',
                'launch',
                str(studio_file),
                '--reliable-images',
            ],
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        if launch_graph
        else None
    )
    try:
        yield launch
    finally:
        if launch is not None:
            stop_process(launch, LAUNCH_STOP_S)


def _stop_spinner(stop: threading.Event, spinner: threading.Thread) -> None:
    """Stop the spin thread and wait for it.

    Destroying entities or the context under a running spin ends the process with a C++ terminate.
    """
    stop.set()
    if spinner.is_alive():
        spinner.join(timeout=5.0)


def _spin(executor, stop: threading.Event, recorder) -> None:
    """Spin the replay node.

    Every half second let the recorder subscribe output topics that appeared.
    """
    next_discovery = 0.0
    while not stop.is_set():
        executor.spin_once(timeout_sec=0.05)
        if time.monotonic() >= next_discovery:
            recorder.discover()
            next_discovery = time.monotonic() + 0.5


def _wait_for_graph(node, recorder, player, launch) -> None:
    """Until every node subscribes the inputs and the recorder has the tracker's outputs."""
    from memo_ros.tools.cli import CliError

    deadline = time.monotonic() + GRAPH_TIMEOUT_S
    while True:
        ready = not player.unmatched_topics() and '/memo/joint_states' in recorder.subscriptions
        if ready:
            break
        if launch is not None and launch.poll() is not None:
            raise CliError('the graph stopped before it was up (see the node log)')
        if time.monotonic() > deadline:
            raise CliError(
                f'the graph did not come up within {GRAPH_TIMEOUT_S:.0f} s; missing: '
                f'{", ".join(player.unmatched_topics()) or "/memo/joint_states"}'
            )
        time.sleep(0.2)


def _wait_for_nodes_side(node, matched, recorder, player) -> None:
    """Until the nodes report on /diagnostics their side of every match the replay needs.

    Each node has then matched every publisher of its inputs (the player's among them) and every
    subscriber of its outputs (the recorder's, the pacer's) that the graph shows here, so the first
    frames are neither lost on their way in nor their results on the way out. A graph whose nodes
    do not report it (not memo_ros nodes) is played into after MATCH_TIMEOUT_S, with a line saying
    so.
    """
    deadline = time.monotonic() + MATCH_TIMEOUT_S
    # (a copy: the spin thread subscribes the recorder to topics as they appear)
    while missing := matched.missing_in_graph(node, player.topics, list(recorder.subscriptions)):
        if time.monotonic() > deadline:
            print(
                f'replay: the nodes did not confirm, within {MATCH_TIMEOUT_S:.0f} s, their side '
                f'of: {", ".join(missing)}; playing anyway',
                file=sys.stderr,
            )
            return
        time.sleep(0.1)


def _drain(recorder, idle: float = DRAIN_IDLE_S, limit: float = 30.0) -> None:
    """Wait until no output arrived for ``idle`` s (the graph has drained), at most ``limit`` s."""

    def outputs() -> int:  # /diagnostics comes every second whatever happens: not a sign of work
        return sum(n for topic, n in recorder.counts.items() if topic != '/diagnostics')

    end = time.monotonic() + limit
    last = outputs()
    quiet_since = time.monotonic()
    while time.monotonic() < end:
        time.sleep(0.2)
        now = outputs()
        if now != last:
            last, quiet_since = now, time.monotonic()
        elif time.monotonic() - quiet_since >= idle:
            return
