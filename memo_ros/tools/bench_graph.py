"""Latency and throughput of the whole live graph fed a 3-camera studio bag at fixed rates (``benchmark graph``).

A studio-arm bag (3 cameras, 640x480 mono8) is simulated once into a
temporary directory (or given with ``--bag``).  For each rate a fresh graph
is started as users start it, ``memo-ros launch STUDIO`` (one contour_node
per camera, selector_node, tracker_node, each its own process), with
best-effort images as from live cameras.  This process plays the bag's
``/<cam>/image_raw`` (best effort) and ``/<cam>/camera_info`` (reliable) with
:class:`BagPlayer` at the rate (with a Fast DDS shared-memory segment large
enough for all cameras, see memo_ros.ros.dds.player_segment), and restamps every frame to the
wall clock at the moment its first message goes out (all messages of a frame
share the stamp).  Every output carries its frame's stamp, so a stage's cumulative
latency is the output's publication time (its DDS source timestamp) minus the
stamp: ``/<cam>/contours``, ``/memo/camera_assignment``, ``/memo/joint_states``
(end to end) and ``/memo/processed`` (every frame the tracker finished, with
its outcome).  The first frames (the empty studio the contour nodes learn
their background from, and the tracker's start) are warm-up and left out of
the statistics; CPU is measured over the timed frames from /proc, peak RSS is
each process's VmHWM.  Frames without joint_states are counted by reason,
and the nodes' own drop counters come from ``/diagnostics``.
"""
from __future__ import annotations

import argparse
import os
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from memo_ros.tools.proc_stats import children, cpu_seconds, log_tail, peak_rss_mb, rss_mb, stop_process

SCENARIO = 'studio-arm'
SIZE = (640, 480)
FRAMES = 330                 # subject frames simulated; the studio adds its empty frames before them
WARMUP = 40                  # first frames of the bag left out of the statistics (10 empty + 30 tracked)
RATES = (30.0, 60.0)
DEFAULT_DOMAIN_ID = 78
GRAPH_TIMEOUT = 90.0         # s for the nodes to start, match and report on /diagnostics
SETTLE = 2.0                 # s after matching (the nodes' readers match the players' writers); idle CPU
DRAIN_IDLE = 10.0            # s without any output after playback: the graph is done (a re-initialisation
                             # from the silhouettes can keep the tracker quiet for seconds)
DRAIN_TIMEOUT = 60.0
RSS_PERIOD = 2.0             # s between resident-memory samples of every process
DIAGNOSTICS_WAIT = 3.0       # s for every node's diagnostics after the drain (they come once a second)
STOP_TIMEOUT = 15.0          # s for the launcher to stop its nodes after SIGINT
SUSTAINED = 0.98             # output rate at least this fraction of the input rate: the graph keeps pace
TARGETS = {30.0: 'zero drops, end-to-end p99 < 50 ms, sustained', 60.0: 'drops < 1 %, sustained'}
ASSIGNMENT_TOPIC = '/memo/camera_assignment'
JOINT_STATES_TOPIC = '/memo/joint_states'
PROCESSED_TOPIC = '/memo/processed'


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The graph suite's options (on the benchmark command's parser)."""
    parser.add_argument('--rates', default=','.join(f'{r:g}' for r in RATES),
                        help='graph: input frame rates, Hz, comma separated (default 30,60)')
    parser.add_argument('--frames', type=int, default=FRAMES,
                        help=f'graph: subject frames of the simulated bag (default {FRAMES}; the studio adds '
                             'its empty frames before them)')
    parser.add_argument('--warmup', type=int, default=WARMUP,
                        help=f'graph: first frames of the bag left out of the statistics (default {WARMUP})')
    parser.add_argument('--bag', type=Path,
                        help='graph: play this bag (studio YAML beside it as BAG.yaml) instead of simulating one')
    parser.add_argument('--loops', type=int, default=1,
                        help='graph: play the bag this many times in a row, stamps going on (a soak; default 1)')
    parser.add_argument('--out', type=Path, help='also write the report as JSON to this file')


def command_words(args: argparse.Namespace) -> list[str]:
    """This suite's options as command-line words (for the report's command line)."""
    words = ['--rates', args.rates, '--warmup', str(args.warmup)] + (['--loops', str(args.loops)] if args.loops > 1 else [])
    return words + (['--bag', str(args.bag)] if args.bag else ['--frames', str(args.frames)])


def parse_rates(text: str) -> list[float]:
    """'30,60' -> [30.0, 60.0]; ValueError for anything not a list of positive numbers."""
    rates = [float(word) for word in text.split(',') if word.strip()]
    if not rates or any(not np.isfinite(r) or r <= 0 for r in rates):
        raise ValueError(f'rates must be positive numbers, not {text!r}')
    return rates


def measure(args: argparse.Namespace) -> dict:
    """The suite's figures for ``memo-ros benchmark graph`` (user errors as CliError)."""
    from memo_ros.tools.cli import CliError
    try:
        rates = parse_rates(args.rates)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    if args.frames < 1 or args.warmup < 0 or args.loops < 1:
        raise CliError('--frames and --loops must be at least 1 and --warmup not negative')
    if args.bag is not None:
        studio = args.bag.with_name(args.bag.name + '.yaml')
        if not args.bag.exists() or not studio.is_file():
            raise CliError(f'need the bag {args.bag} and its studio file {studio}')
    return run_graph_benchmark(rates, args.frames, args.warmup, args.bag, loops=args.loops)


# ------------------------------------------------------------------ frames


def header_stamp_ns(cdr: bytes) -> int:
    """The header stamp of a serialized message that starts with a std_msgs/Header."""
    endian = '<' if cdr[1] & 1 else '>'            # CDR encapsulation: 0x0001 little, 0x0000 big endian
    sec, nanosec = struct.unpack_from(endian + 'iI', cdr, 4)
    return sec * 1_000_000_000 + nanosec


def restamped(cdr: bytes, stamp_ns: int) -> bytes:
    """The serialized message with its header stamp replaced (the stamp follows the 4-byte encapsulation)."""
    endian = '<' if cdr[1] & 1 else '>'
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    return cdr[:4] + struct.pack(endian + 'iI', sec, nanosec) + cdr[12:]


@dataclass
class FrameTrace:
    """One frame as it went through the graph: its stamp and the publication time (ns) of each output."""

    index: int                                   # frame of the bag, from 0
    stamp: int                                   # wall clock when its first message went out
    contours: dict[str, int] = field(default_factory=dict)
    assignment: int | None = None
    joint_states: int | None = None
    processed: int | None = None
    outcome: str | None = None


class Restamper:
    """BagPlayer hook: each frame (a bag stamp) gets the wall-clock time when its first message goes out.

    Both players (images and camera_info) call it from their own threads; a frame's later
    messages get the same stamp, so the frame keeps one stamp through the whole graph."""

    def __init__(self, on_frame=None) -> None:
        self.on_frame = on_frame
        self.frames: dict[int, FrameTrace] = {}       # new stamp -> trace
        self.messages: dict[str, int] = {}            # topic -> messages published
        self._stamps: dict[tuple[int, int], int] = {}   # (pass through the bag, bag stamp) -> new stamp
        self._lock = threading.Lock()
        self._player = threading.local()              # each player thread counts its own passes

    def before_publish(self, item) -> None:
        original = header_stamp_ns(item.data)
        player = self._player
        if original < getattr(player, 'last', original):      # the bag starts again (--loops)
            player.passes = getattr(player, 'passes', 0) + 1
        player.last = original
        key = (getattr(player, 'passes', 0), original)
        with self._lock:
            stamp = self._stamps.get(key)
            if stamp is None:
                newest = max(self._stamps.values(), default=0)
                stamp = self._stamps[key] = max(time.time_ns(), newest + 1)
                trace = self.frames[stamp] = FrameTrace(len(self.frames), stamp)
                if self.on_frame is not None:
                    self.on_frame(trace)
            self.messages[item.topic] = self.messages.get(item.topic, 0) + 1
        item.data = restamped(item.data, stamp)


class Probe:
    """Subscribes the graph's outputs and files each message's publication time under its frame."""

    def __init__(self, node, cameras: list[str], frames: dict[int, FrameTrace], on_processed=None) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from sensor_msgs.msg import JointState, PointCloud2
        from std_msgs.msg import Header

        from memo_ros.ros.dds import qos_profile

        self.frames = frames
        self.on_processed = on_processed
        self.unknown = 0                              # outputs whose stamp is no published frame's
        self.last_output = time.monotonic()
        self.diagnostics: dict[str, dict] = {}        # node label -> {'values': ..., 'time': monotonic}
        self.frame_ms: dict[str, list[tuple[float, float]]] = {}   # node label -> (monotonic, last_frame_ms)
        reliable = qos_profile('reliable', 1000)
        self.topics = [f'/{c}/contours' for c in cameras] + [ASSIGNMENT_TOPIC, JOINT_STATES_TOPIC, PROCESSED_TOPIC]
        for cam in cameras:
            node.create_subscription(PointCloud2, f'/{cam}/contours',
                                     lambda data, info, cam=cam: self._on_contours(cam, data, info), reliable,
                                     raw=True)
        node.create_subscription(DiagnosticArray, ASSIGNMENT_TOPIC, self._on_assignment, reliable, raw=True)
        node.create_subscription(JointState, JOINT_STATES_TOPIC, self._on_joint_states, reliable, raw=True)
        node.create_subscription(Header, PROCESSED_TOPIC, self._on_processed, reliable)
        node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, qos_profile('reliable', 100))

    def _trace(self, stamp: int) -> FrameTrace | None:
        self.last_output = time.monotonic()
        trace = self.frames.get(stamp)
        if trace is None:
            self.unknown += 1
        return trace

    def _on_contours(self, cam: str, data: bytes, info: dict) -> None:
        if (trace := self._trace(header_stamp_ns(data))) is not None:
            trace.contours.setdefault(cam, published_ns(info))

    def _on_assignment(self, data: bytes, info: dict) -> None:
        if (trace := self._trace(header_stamp_ns(data))) is not None and trace.assignment is None:
            trace.assignment = published_ns(info)

    def _on_joint_states(self, data: bytes, info: dict) -> None:
        if (trace := self._trace(header_stamp_ns(data))) is not None and trace.joint_states is None:
            trace.joint_states = published_ns(info)

    def _on_processed(self, msg, info: dict) -> None:
        trace = self._trace(msg.stamp.sec * 1_000_000_000 + msg.stamp.nanosec)
        if trace is not None and trace.processed is None:
            trace.processed, trace.outcome = published_ns(info), msg.frame_id
            if self.on_processed is not None:
                self.on_processed(trace)

    def _on_diagnostics(self, msg) -> None:
        now = time.monotonic()
        for status in msg.status:
            label = status.name.strip('/')
            values = {kv.key: kv.value for kv in status.values}
            self.diagnostics[label] = {'values': values, 'time': now}
            if 'last_frame_ms' in values:
                self.frame_ms.setdefault(label, []).append((now, float(values['last_frame_ms'])))


def published_ns(info: dict) -> int:
    """When the publisher wrote the message: its DDS source timestamp (system clock, ns)."""
    return int(info.get('source_timestamp') or info.get('received_timestamp') or time.time_ns())


# ------------------------------------------------------------------ processes


def node_label(command: list[str]) -> str:
    """'cam_front/contour_node', 'selector_node', ...: the launcher's label of a node's command line."""
    module = command[command.index('-m') + 1] if '-m' in command else Path(command[0]).name
    name = module.rsplit('.', 1)[-1]
    namespace = next((w.split(':=', 1)[1].strip('/') for w in command if w.startswith('__ns:=')), '')
    return f'{namespace}/{name}' if namespace else name


def start_graph(studio_file: Path, env: dict, log: Path) -> subprocess.Popen:
    """``memo-ros launch STUDIO`` (best-effort images, as for live cameras), its output to ``log``."""
    with open(log, 'w') as out:
        return subprocess.Popen([sys.executable, '-m', 'memo_ros.tools.cli', 'launch', str(studio_file)],
                                env=env, stdout=out, stderr=subprocess.STDOUT)


def wait_for_nodes(launch: subprocess.Popen, expected: int, log: Path) -> dict[int, str]:
    """The launcher's node processes (pid -> label), once all ``expected`` run."""
    from memo_ros.tools.cli import CliError
    deadline = time.monotonic() + GRAPH_TIMEOUT
    while True:
        # a child just forked still shows the launcher's command line until it execs its node: wait for that
        nodes = {pid: node_label(command) for pid, command in children(launch.pid).items()
                 if any('memo_ros.nodes.' in word for word in command)}
        if len(nodes) >= expected:
            return nodes
        if launch.poll() is not None:
            raise CliError(f'the graph stopped before it was up: {log_tail(log)}')
        if time.monotonic() > deadline:
            raise CliError(f'{len(nodes)} of {expected} nodes started within {GRAPH_TIMEOUT:g} s')
        time.sleep(0.1)


def stop_graph(launch: subprocess.Popen, nodes: dict[int, str]) -> None:
    """SIGINT to the launcher (it stops its nodes); kill it, then any node of it left, on a timeout."""
    nodes = nodes or (children(launch.pid) if launch.poll() is None else {})    # stopped while starting
    stop_process(launch, STOP_TIMEOUT)
    for pid in nodes:
        try:
            with open(f'/proc/{pid}/cmdline', 'rb') as f:
                still_ours = b'memo_ros.nodes.' in f.read()
            if still_ours:
                os.kill(pid, signal.SIGKILL)
        except (OSError, ProcessLookupError):
            pass                                         # ended, as it should have


def cpu_snapshot(pids: dict[int, str]) -> tuple[float, dict[int, float]]:
    """(monotonic time, CPU seconds per pid) now; a process that ended is left out."""
    now = time.monotonic()
    cpu = {}
    for pid in pids:
        try:
            cpu[pid] = cpu_seconds(pid)
        except OSError:
            pass
    return now, cpu


# ------------------------------------------------------------------ one rate


def run_rate(bag: Path, studio_file: Path, cameras: list[str], expected_nodes: int, rate_hz: float,
             bag_hz: float, warmup: int, domain_id: int, env: dict, log: Path, loops: int = 1) -> dict:
    """Launch a fresh graph, play the bag into it ``loops`` times at ``rate_hz`` frames/s, and measure it."""
    from memo_ros.ros.dds import ros_session
    from memo_ros.tools.bag import BagPlayer, PlayOptions
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
        rss_samples: list[tuple[int, dict[int, float | None]]] = []      # (frames published, pid -> MB)
        with ros_session('memo_graph_benchmark', domain_id) as (node, executor):
            probe = Probe(node, cameras, restamper.frames, on_processed)
            selector = any(label == 'selector_node' for label in nodes.values())
            options = dict(rate=rate_hz / bag_hz, wait_timeout=GRAPH_TIMEOUT)
            players = [BagPlayer(node, bag, PlayOptions(topics=[f'/{c}/image_raw' for c in cameras],
                                                        reliability='best_effort', wait_for_subscribers=1,
                                                        **options), before_publish=restamper.before_publish),
                       BagPlayer(node, bag, PlayOptions(topics=[f'/{c}/camera_info' for c in cameras],
                                                        reliability='reliable',
                                                        wait_for_subscribers=2 if selector else 1, **options),
                                 before_publish=restamper.before_publish)]
            try:
                _wait_for_graph(node, executor, players, probe, set(nodes.values()), launch, log)
                window['idle'] = _settle(executor, pids)
                stop = threading.Event()
                threads = [threading.Thread(target=_play_passes, args=(p, stop, loops), daemon=True)
                           for p in players]
                for thread in threads:
                    thread.start()
                try:
                    next_sample = 0.0
                    while any(thread.is_alive() for thread in threads):
                        executor.spin_once(timeout_sec=0.02)
                        if time.monotonic() >= next_sample:         # memory over the run (a soak's growth)
                            rss_samples.append((len(restamper.frames), _rss(pids)))
                            next_sample = time.monotonic() + RSS_PERIOD
                finally:
                    stop.set()
                    for thread in threads:
                        thread.join()
                _drain(executor, probe, restamper)
                drained = time.monotonic()
                window.setdefault('end', cpu_snapshot(pids))
                deadline = drained + DIAGNOSTICS_WAIT
                while time.monotonic() < deadline and \
                        any(probe.diagnostics.get(n, {}).get('time', 0.0) < drained for n in nodes.values()):
                    executor.spin_once(timeout_sec=0.05)
                peak_rss = {pid: _peak_rss(pid) for pid in pids}
                rss_samples.append((len(restamper.frames), _rss(pids)))
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


def _rss(pids: dict[int, str]) -> dict[int, float | None]:
    out = {}
    for pid in pids:
        try:
            out[pid] = rss_mb(pid)
        except OSError:
            out[pid] = None
    return out


def memory_growth(pids: dict[int, str], samples: list[tuple[int, dict]], warmup: int) -> list[dict]:
    """Per process: resident memory once warm (the first sample after the warm-up frames and a tenth of
    the run), at the end, and the growth between them, MB."""
    rows = []
    total = samples[-1][0] if samples else 0
    warm = [s for s in samples if s[0] >= max(warmup, total // 10)] or samples
    for pid, label in pids.items():
        start = next((mb[pid] for _, mb in warm if mb.get(pid) is not None), None)
        end = next((mb[pid] for _, mb in reversed(samples) if mb.get(pid) is not None), None)
        rows.append({'process': label, 'rss_warm_mb': start, 'rss_end_mb': end,
                     'growth_mb': end - start if start is not None and end is not None else None,
                     'samples': len(samples)})
    return rows


def _peak_rss(pid: int) -> float | None:
    try:
        return peak_rss_mb(pid)
    except OSError:
        return None


def _wait_for_graph(node, executor, players, probe: Probe, labels: set[str], launch, log: Path) -> None:
    """Until the players' topics have their subscribers, the probe its publishers, and every node reported."""
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
            raise CliError(f'the graph did not come up within {GRAPH_TIMEOUT:g} s; missing: {", ".join(missing)}')
        executor.spin_once(timeout_sec=0.05)


def _settle(executor, pids: dict[int, str]) -> tuple:
    """Spin SETTLE s with the graph up and idle; the CPU snapshots before and after (the idle CPU)."""
    before = cpu_snapshot(pids)
    settle = time.monotonic() + SETTLE
    while time.monotonic() < settle:
        executor.spin_once(timeout_sec=0.05)
    return before, cpu_snapshot(pids)


def _drain(executor, probe: Probe, restamper: Restamper) -> None:
    """Spin until the tracker finished the last frame (it reports every frame it heard of, in order or
    skipped), or no output came for DRAIN_IDLE s (frames it never heard of), at most DRAIN_TIMEOUT s."""
    last = max(restamper.frames.values(), key=lambda t: t.index, default=None)
    deadline = time.monotonic() + DRAIN_TIMEOUT
    probe.last_output = time.monotonic()
    while time.monotonic() < deadline and time.monotonic() - probe.last_output < DRAIN_IDLE:
        if last is not None and last.processed is not None:
            break
        executor.spin_once(timeout_sec=0.05)


# ------------------------------------------------------------------ figures


def percentiles(values_ms: list[float]) -> dict | None:
    """p50, p99, mean and max of latencies (ms), with their count; None without any."""
    if not values_ms:
        return None
    v = np.asarray(values_ms)
    return {'n': int(v.size), 'p50': float(np.percentile(v, 50)), 'p99': float(np.percentile(v, 99)),
            'mean': float(v.mean()), 'max': float(v.max())}


def drop_reason(trace: FrameTrace, cameras: list[str]) -> str | None:
    """Why a frame has no joint_states (None: it has)."""
    if trace.joint_states is not None:
        return None
    if trace.outcome is not None:
        return f'tracker: {trace.outcome}' if trace.outcome != 'tracking' else 'joint_states not received here'
    if not trace.contours and trace.assignment is None:
        return 'no contours nor assignment (lost before or in the nodes)'
    return f'never finished by the tracker (contours {len(trace.contours)}/{len(cameras)}, ' \
           f'assignment {"yes" if trace.assignment is not None else "no"})'


def rate_figures(rate_hz: float, cameras: list[str], warmup: int, restamper: Restamper, probe: Probe,
                 pids: dict[int, str], window: dict, peak_rss: dict[int, float | None]) -> dict:
    """Latencies, rates, drops and per-process figures of one rate's run from the frame traces."""
    ms = 1e-6
    frames = sorted(restamper.frames.values(), key=lambda t: t.index)
    timed = [t for t in frames if t.index >= warmup]
    contours_last = [ms * (max(t.contours.values()) - t.stamp) for t in timed if len(t.contours) == len(cameras)]
    e2e = [ms * (t.joint_states - t.stamp) for t in timed if t.joint_states is not None]
    # the tracker's own share: from its last input's publication to joint_states
    tracker_stage = [ms * (t.joint_states - max([*t.contours.values(), t.assignment or 0])) for t in timed
                     if t.joint_states is not None and t.contours]
    drops: dict[str, int] = {}
    outcomes: dict[str, int] = {}
    for t in timed:
        if (reason := drop_reason(t, cameras)) is not None:
            drops[reason] = drops.get(reason, 0) + 1
        if t.outcome is not None:
            outcomes[t.outcome] = outcomes.get(t.outcome, 0) + 1
    out_stamps = sorted(t.joint_states for t in timed if t.joint_states is not None)
    in_span = (timed[-1].stamp - timed[0].stamp) * 1e-9 if len(timed) > 1 else 0.0
    out_span = (out_stamps[-1] - out_stamps[0]) * 1e-9 if len(out_stamps) > 1 else 0.0
    tenth = max(len(e2e) // 10, 1)
    result = {
        'rate_hz': rate_hz, 'frames_published': len(frames), 'warmup_frames': min(warmup, len(frames)),
        'timed_frames': len(timed), 'frames_out': len(e2e), 'frames_dropped': len(timed) - len(e2e),
        'drop_pct': 100.0 * (len(timed) - len(e2e)) / len(timed) if timed else None,
        'drops': dict(sorted(drops.items(), key=lambda kv: -kv[1])), 'outcomes': outcomes,
        'contours_missing': {c: sum(c not in t.contours for t in timed) for c in cameras},
        'input_fps': (len(timed) - 1) / in_span if in_span > 0 else None,
        'output_fps': (len(out_stamps) - 1) / out_span if out_span > 0 else None,
        'latency_ms': {
            'contours': percentiles(contours_last),
            'contours_per_camera': {c: percentiles([ms * (t.contours[c] - t.stamp) for t in timed if c in t.contours])
                                    for c in cameras},
            'assignment': percentiles([ms * (t.assignment - t.stamp) for t in timed if t.assignment is not None]),
            'joint_states': percentiles(e2e),
            'processed': percentiles([ms * (t.processed - t.stamp) for t in timed if t.processed is not None]),
        },
        'stage_ms': {'contour_node': percentiles(contours_last),
                     'selector_node': percentiles([ms * (t.assignment - t.stamp) for t in timed
                                                   if t.assignment is not None]),
                     'tracker_node': percentiles(tracker_stage)},
        'e2e_drift_ms': float(np.median(e2e[-tenth:]) - np.median(e2e[:tenth])) if e2e else None,
        'outputs_without_frame': probe.unknown,
        'per_frame': {   # every timed frame, for plots: bag index, tracker outcome, latencies (ms, None: none)
            'index': [t.index for t in timed], 'outcome': [t.outcome for t in timed],
            'contours_ms': [round(ms * (max(t.contours.values()) - t.stamp), 2) if t.contours else None
                            for t in timed],
            'assignment_ms': [round(ms * (t.assignment - t.stamp), 2) if t.assignment else None for t in timed],
            'joint_states_ms': [round(ms * (t.joint_states - t.stamp), 2) if t.joint_states else None
                                for t in timed]},
        'messages_published': dict(sorted(restamper.messages.items())),
        'processes': _process_figures(pids, window, peak_rss, _frames_handled(timed, cameras), probe.frame_ms),
        'nodes': _node_figures(probe.diagnostics, restamper.messages, pids),
    }
    per_frame = [p['cpu_ms_per_frame'] for p in result['processes'] if p['process'] in result['nodes']]
    # what one frame costs when every node handles it: the CPU the rate needs, whatever the machine's load
    result['nodes_cpu_ms_per_frame'] = float(sum(per_frame)) if per_frame and None not in per_frame else None
    result['target'] = target_check(result)
    return result


def _frames_handled(timed: list[FrameTrace], cameras: list[str]) -> dict[str, int]:
    """Timed frames each node worked on: contours published, assignments published, frames tracked (not
    skipped or late)."""
    handled = {f'{c}/contour_node': sum(c in t.contours for t in timed) for c in cameras}
    handled['selector_node'] = sum(t.assignment is not None for t in timed)
    handled['tracker_node'] = sum(t.outcome not in (None, 'skipped', 'late') for t in timed)
    return handled


def _cpu_between(start: tuple | None, end: tuple | None, pid: int) -> tuple[float, float] | None:
    """(CPU seconds, wall seconds) of ``pid`` between two snapshots (None when not in both)."""
    if start and end and pid in start[1] and pid in end[1] and end[0] > start[0]:
        return end[1][pid] - start[1][pid], end[0] - start[0]
    return None


def _process_figures(pids: dict[int, str], window: dict, peak_rss: dict[int, float | None],
                     handled: dict[str, int], frame_ms: dict[str, list[tuple[float, float]]]) -> list[dict]:
    """Per process: CPU % over the timed frames (first timed frame published to the last one the tracker
    finished) and while idle before playback, CPU per frame handled, the median of the frame times the node
    reported on /diagnostics during the timed frames (wall time of one frame's work), peak RSS."""
    rows = []
    start = window.get('start')
    for pid, label in pids.items():
        busy = _cpu_between(start, window.get('end'), pid)
        idle = _cpu_between(*window.get('idle', (None, None)), pid)
        frames = handled.get(label)
        reported = [ms for t, ms in frame_ms.get(label, []) if start and t >= start[0]]
        rows.append({'process': label, 'pid': pid,
                     'cpu_pct': 100.0 * busy[0] / busy[1] if busy else None,
                     'idle_cpu_pct': 100.0 * idle[0] / idle[1] if idle else None,
                     'frames_handled': frames,
                     'cpu_ms_per_frame': 1000.0 * busy[0] / frames if busy and frames else None,
                     'reported_frame_ms': float(np.median(reported)) if reported else None,
                     'peak_rss_mb': peak_rss.get(pid)})
    return rows


def _node_figures(diagnostics: dict[str, dict], messages: dict[str, int], pids: dict[int, str]) -> dict:
    """Each node's counters from its last /diagnostics (whole run, warm-up included) and drops by reason."""
    nodes = {}
    for label in pids.values():
        if label not in diagnostics:
            continue
        values = diagnostics[label]['values']
        counters = {k: int(v) for k, v in values.items() if v.lstrip('-').isdigit() and not k.startswith('dropped.')}
        dropped = {k.removeprefix('dropped.'): int(v) for k, v in values.items()
                   if k.startswith('dropped.') and k != 'dropped.total' and int(v)}
        entry = {'counters': counters, 'dropped': dropped}
        if label.endswith('/contour_node'):       # images that never reached the node (best-effort transport)
            published = messages.get(f'/{label.split("/")[0]}/image_raw', 0)
            entry['images_lost_before_node'] = published - counters.get('frames_in', 0)
        if 'last_frame_ms' in values:
            entry['last_frame_ms'] = float(values['last_frame_ms'])
        nodes[label] = entry
    return nodes


def target_check(r: dict) -> dict | None:
    """The issue's target for this rate, and whether this run met it (None for rates without one)."""
    target = TARGETS.get(r['rate_hz'])
    if target is None or not r['timed_frames']:
        return None
    sustained = r['output_fps'] is not None and r['output_fps'] >= SUSTAINED * r['rate_hz']
    e2e = r['latency_ms']['joint_states']
    if r['rate_hz'] == 30.0:
        met = sustained and r['frames_dropped'] == 0 and e2e is not None and e2e['p99'] < 50.0
    else:
        met = sustained and r['drop_pct'] < 1.0
    return {'target': target, 'sustained': sustained, 'met': bool(met)}


# ------------------------------------------------------------------ the suite


def run_graph_benchmark(rates=RATES, frames: int = FRAMES, warmup: int = WARMUP, bag: Path | None = None,
                        domain_id: int | None = None, loops: int = 1) -> dict:
    """Simulate the bag once (unless given), then run a fresh graph at every rate; the report."""
    from memo_ros.core.imaging import ImagingOptions
    from memo_ros.core.studio import Studio
    from memo_ros.ros.dds import player_segment, player_segment_bytes
    from memo_ros.tools.bag import bag_summary
    from memo_ros.tools.launch import graph_commands
    from memo_ros.tools.simulate import simulate
    if domain_id is None:
        domain_id = int(os.environ.get('ROS_DOMAIN_ID') or DEFAULT_DOMAIN_ID)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'          # this process's participant too
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id), PYTHONUNBUFFERED='1')
    with tempfile.TemporaryDirectory(prefix='memo_ros_bench_graph_') as tmp:
        simulated = bag is None
        if simulated:
            bag = simulate(SCENARIO, Path(tmp) / 'bag', frames=frames, width=SIZE[0], height=SIZE[1],
                           options=ImagingOptions()).bag
        studio_file = bag.with_name(bag.name + '.yaml')
        studio = Studio.load(studio_file)
        cameras = studio.camera_names
        segment = player_segment_bytes(studio.cameras)
        summary = bag_summary(bag)
        images = {t.topic: t.count for t in summary.topics}.get(f'/{cameras[0]}/image_raw', 0)
        seconds = summary.duration_ns * 1e-9
        bag_hz = (images - 1) / seconds if images > 1 and seconds > 0 else studio.frame_rate
        expected = len(graph_commands(studio, studio_file))
        # only for this process's participants: the nodes got ``env`` from before
        with player_segment(segment, tmp, localhost_only=True) as own_profile:
            rows = [run_rate(bag, studio_file, cameras, expected, rate, bag_hz, warmup, domain_id, env,
                             Path(tmp) / f'graph_{k}.log', loops) for k, rate in enumerate(rates)]
        first = cameras[0]
        size = next((f'{c.width}x{c.height}' for c in studio.cameras if c.name == first), '?')
    return {'cpus': len(os.sched_getaffinity(0)), 'bag': 'simulated' if simulated else str(bag),
            'scenario': SCENARIO if simulated else studio.name, 'cameras': cameras, 'size': size,
            'bag_frames': images, 'bag_hz': bag_hz, 'images': 'best_effort',
            'player_shm_segment_mb': segment / 2**20 if own_profile else None,
            'warmup_frames': warmup, 'domain_id': domain_id, 'rates': rows}


def _f(value, spec: str = '.1f') -> str:
    return '-' if value is None else format(value, spec)


def _p(stats: dict | None) -> str:
    return '-' if stats is None else f'{stats["p50"]:.1f}/{stats["p99"]:.1f}'


def print_graph_benchmark(report: dict) -> None:
    """Per rate: latencies, rates, drops; then per process CPU and memory; then the nodes' drop counters."""
    rows = report['rates']
    print(f'graph: {report["scenario"]} ({report["bag"]}), {len(report["cameras"])} cameras '
          f'{report["size"]}, {report["bag_frames"]} frames recorded at {report["bag_hz"]:.0f} Hz; '
          f'`memo-ros launch STUDIO`, best-effort images (as from live cameras); ROS_DOMAIN_ID {report["domain_id"]}')
    print(f'every frame restamped to the wall clock when it goes out; latency = output publication (DDS source '
          f'timestamp) - stamp; the first {report["warmup_frames"]} frames are warm-up (background learning, '
          f'tracker start), not counted')
    if report.get('player_shm_segment_mb'):
        print(f'the player (this process, all cameras) has a {report["player_shm_segment_mb"]:.0f} MiB Fast DDS '
              f'shared-memory segment, as separate camera drivers would have between them')
    print()
    print(f'{"rate":>5} {"in/s":>5} {"out/s":>6} {"out/timed":>10} {"drop %":>6}  '
          f'{"contours":>11} {"selector":>11} {"tracker":>11} {"end to end":>11} {"drift":>6}  target')
    print(f'{"Hz":>5} {"":>5} {"":>6} {"":>10} {"":>6}  {"p50/p99 ms":>11} {"p50/p99 ms":>11} '
          f'{"p50/p99 ms":>11} {"p50/p99 ms":>11} {"ms":>6}')
    for r in rows:
        target = r['target']
        verdict = '-' if target is None else f'{"met" if target["met"] else "NOT met"} ({target["target"]})'
        print(f'{r["rate_hz"]:>5.0f} {_f(r["input_fps"]):>5} {_f(r["output_fps"]):>6} '
              f'{r["frames_out"]:>4}/{r["timed_frames"]:<5} {_f(r["drop_pct"], ".2f"):>6}  '
              f'{_p(r["stage_ms"]["contour_node"]):>11} {_p(r["stage_ms"]["selector_node"]):>11} '
              f'{_p(r["stage_ms"]["tracker_node"]):>11} {_p(r["latency_ms"]["joint_states"]):>11} '
              f'{_f(r["e2e_drift_ms"]):>6}  {verdict}')
    print()
    print('contours = publication of the last of the cameras\' contours; selector = the assignment (it starts on '
          'camera_info, beside the contour nodes); tracker = joint_states after the later of the two; end to end = '
          'joint_states; drift = median end to end of the last tenth of the frames - of the first tenth')
    print()
    for r in rows:
        drops = ', '.join(f'{n} {reason}' for reason, n in r['drops'].items()) or 'none'
        missing = ', '.join(f'{c} {n}' for c, n in r['contours_missing'].items() if n) or 'none'
        print(f'{r["rate_hz"]:.0f} Hz: frames without joint_states: {drops}; contours missing: {missing}')
    print()
    labels = list(dict.fromkeys(p['process'] for r in rows for p in r['processes']))
    columns = ('cpu_pct', 'idle_cpu_pct', 'cpu_ms_per_frame', 'reported_frame_ms', 'peak_rss_mb')
    print(f'{"":<26}' + ''.join(' ' + format(f'{r["rate_hz"]:.0f} Hz', '<38') for r in rows))
    print(f'{"process":<26}' + f' {"CPU %":>6} {"idle %":>6} {"CPU ms/f":>8} {"frame ms":>8} {"RSS MB":>6}' * len(rows))
    for label in labels:
        line = f'{label:<26}'
        for r in rows:
            p = next((p for p in r['processes'] if p['process'] == label), {})
            line += ''.join(f' {_f(p.get(k), ".0f" if k == "peak_rss_mb" else ".1f"):>{w}}'
                            for k, w in zip(columns, (6, 6, 8, 8, 6)))
        print(line)
    line = f'{"all":<26}'
    for r in rows:
        busy = sum(p['cpu_pct'] or 0.0 for p in r['processes'])
        idle = sum(p['idle_cpu_pct'] or 0.0 for p in r['processes'])
        line += f' {busy:>6.1f} {idle:>6.1f} {"":>8} {"":>8} {"":>6}'
    print(line)
    for r in rows:
        if r['nodes_cpu_ms_per_frame'] is not None:
            need = r['nodes_cpu_ms_per_frame'] * r['rate_hz'] / 1000.0
            print(f'{r["rate_hz"]:.0f} Hz: one frame through every node costs {r["nodes_cpu_ms_per_frame"]:.1f} ms '
                  f'of CPU (sum of CPU ms/f), so {r["rate_hz"]:.0f} frames/s need {need:.2f} cores '
                  f'({report.get("cpus", "?")} here)')
    print('CPU % of one core, from the first timed frame to the last frame the tracker finished; idle % = the graph up '
          f'and fed nothing ({SETTLE:g} s before playback); CPU ms/f = CPU time per frame the node worked on '
          '(tracker: tracked, not skipped); frame ms = median of the per-frame work time the node reports on '
          '/diagnostics (once a second); RSS = peak (VmHWM)')
    for r in rows:
        growth = [m for m in r.get('memory', []) if m['growth_mb'] is not None]
        if growth:
            print(f'{r["rate_hz"]:.0f} Hz, bag played {r.get("loops", 1)}x: resident memory warm -> end (growth), MB: '
                  + ', '.join(f'{m["process"]} {m["rss_warm_mb"]:.0f} -> {m["rss_end_mb"]:.0f} '
                              f'({m["growth_mb"]:+.1f})' for m in growth))
    print()
    print('node drop counters (whole run, warm-up included), from /diagnostics:')
    for r in rows:
        for label, n in r['nodes'].items():
            dropped = ', '.join(f'{k} {v}' for k, v in n['dropped'].items())
            lost = n.get('images_lost_before_node')
            extra = f'; images lost before the node {lost}' if lost else ''
            print(f'  {r["rate_hz"]:.0f} Hz {label:<24} {dropped or "none"}{extra}')
