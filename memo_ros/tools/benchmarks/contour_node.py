"""Sustained throughput of contour_node as its own process.

Fed a bag over real DDS at 30 and 60 Hz.

A studio-walk bag (640x480, mono8, 30 frames/s) is simulated once.  For each case a fresh
``contour_node`` process is started on ``/cam_front``; this process subscribes its ``contours`` and
``/diagnostics``, waits until the node's subscriptions have matched, then plays only
``/cam_front/image_raw`` and ``/cam_front/camera_info`` with :class:`BagPlayer` at rate 1 (30 Hz)
or 2 (60 Hz).  Cases: reliable images (bag replay) and best-effort images (the live case).  Figures
per case: frames published, contours received, the node's last diagnostics (processed, frames_in,
dropped by reason, last_frame_ms), the sustained output rate and inter-arrival times, the node's
CPU use over the playback (from /proc/<pid>/stat) and its peak RSS (VmHWM). Stamps are simulated,
so no end-to-end latency is reported.
"""

from __future__ import annotations

import os
from pathlib import Path
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np

from memo_ros.tools.proc_stats import cpu_seconds, log_tail, peak_rss_mb, stop_process

SCENARIO = 'studio-walk'
CAMERA = 'cam_front'
SIZE = (640, 480)
FRAMES = 120  # walking frames simulated (the studio adds its empty frames before them)
FRAME_RATE = 30.0
BACKGROUND_FRAMES = 5
CASES = (('reliable', 1.0), ('reliable', 2.0), ('best_effort', 1.0), ('best_effort', 2.0))
DEFAULT_DOMAIN_ID = 77
MATCH_TIMEOUT = 30.0  # s for the node to start and its subscriptions to match
SETTLE = 0.5  # s after matching, so both peers have matched each other
IDLE_END = 1.5  # s without a new contours message after playback: the node is done
DRAIN_TIMEOUT = 30.0
DIAGNOSTICS_PERIOD = 1.0  # the node's NodeHealth period


def _start_node(env: dict, reliable: bool, log: Path) -> subprocess.Popen:
    args = [
        sys.executable,
        '-m',
        'memo_ros.nodes.contour_node',
        '--ros-args',
        '-r',
        f'__ns:=/{CAMERA}',
        '-p',
        f'reliable_images:={"true" if reliable else "false"}',
        '-p',
        f'background_frames:={BACKGROUND_FRAMES}',
    ]
    with open(log, 'w') as out:
        return subprocess.Popen(args, env=env, stdout=out, stderr=subprocess.STDOUT)


def run_case(
    bag: Path, reliability: str, rate: float, domain_id: int, env: dict, log: Path
) -> dict:
    """One node process fed the camera's images at ``rate`` x the recorded rate; its figures."""
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import PointCloud2

    from memo_ros.ros.dds import qos_profile, ros_session
    from memo_ros.tools.bag.play import BagPlayer, PlayOptions

    image_topic, info_topic, contour_topic = (
        f'/{CAMERA}/image_raw',
        f'/{CAMERA}/camera_info',
        f'/{CAMERA}/contours',
    )
    process = _start_node(env, reliability == 'reliable', log)
    try:
        pid = process.pid
        with ros_session('contour_node_benchmark', domain_id) as (node, executor):
            arrivals: list[float] = []
            cpu_at_arrival: list[float] = []
            published: list[float] = []
            diagnostics: dict = {'values': {}, 'time': 0.0}

            def on_contours(msg) -> None:
                arrivals.append(time.monotonic())
                cpu_at_arrival.append(cpu_seconds(pid))

            def on_diagnostics(msg) -> None:
                for status in msg.status:
                    if status.hardware_id == CAMERA:
                        diagnostics['values'] = {kv.key: kv.value for kv in status.values}
                        diagnostics['time'] = time.monotonic()

            node.create_subscription(
                PointCloud2, contour_topic, on_contours, qos_profile('reliable', 10)
            )
            node.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, 10)
            # camera_info always reliable: the node subscribes it reliably, so a best-effort
            # camera_info publisher would never match (no image would get its size check)
            feeds = (
                [(image_topic, info_topic)]
                if reliability == 'reliable'
                else [(image_topic,), (info_topic,)]
            )

            def after_publish(item) -> None:
                if item.topic == image_topic:
                    published.append(time.monotonic())

            players = [
                BagPlayer(
                    node,
                    bag,
                    PlayOptions(
                        rate=rate,
                        topics=list(topics),
                        reliability=reliability if image_topic in topics else 'reliable',
                        wait_for_subscribers=1,
                    ),
                    after_publish=after_publish,
                )
                for topics in feeds
            ]
            try:
                deadline = time.monotonic() + MATCH_TIMEOUT
                while (
                    unmatched := sorted(t for p in players for t in p.unmatched_topics())
                ) or node.count_publishers(contour_topic) < 1:
                    if process.poll() is not None:
                        raise RuntimeError(
                            f'contour_node exited with {process.returncode}:\n{log_tail(log)}'
                        )
                    if time.monotonic() > deadline:
                        raise RuntimeError(
                            f'contour_node did not match within {MATCH_TIMEOUT:g} s: '
                            f'{unmatched or [contour_topic]}'
                        )
                    executor.spin_once(timeout_sec=0.05)
                settle_end = time.monotonic() + SETTLE
                while time.monotonic() < settle_end:
                    executor.spin_once(timeout_sec=0.05)

                stop = threading.Event()
                cpu_start = cpu_seconds(pid)
                play_start = time.monotonic()
                threads = [
                    threading.Thread(target=p.play, args=(stop,), daemon=True) for p in players
                ]
                for thread in threads:
                    thread.start()
                try:
                    while any(thread.is_alive() for thread in threads):
                        executor.spin_once(timeout_sec=0.05)
                finally:
                    stop.set()
                    for thread in threads:
                        thread.join()
                play_end = time.monotonic()
                # drain: until no contours for IDLE_END s and a diagnostics report sent after that
                # quiet moment
                deadline = play_end + DRAIN_TIMEOUT
                while time.monotonic() < deadline:
                    executor.spin_once(timeout_sec=0.05)
                    last = max(arrivals[-1] if arrivals else play_end, play_end)
                    now = time.monotonic()
                    if (
                        now - last >= IDLE_END
                        and diagnostics['time'] > last + IDLE_END - DIAGNOSTICS_PERIOD + 0.1
                    ):
                        break
                peak_rss = peak_rss_mb(pid)
                if process.poll() is not None:
                    raise RuntimeError(
                        f'contour_node exited with {process.returncode}:\n{log_tail(log)}'
                    )
            finally:
                for player in players:
                    player.close()
    finally:
        stop_process(process)
    return _figures(
        reliability,
        rate,
        published,
        arrivals,
        cpu_at_arrival,
        cpu_start,
        play_start,
        peak_rss,
        diagnostics['values'],
    )


def _figures(
    reliability: str,
    rate: float,
    published: list[float],
    arrivals: list[float],
    cpu_at_arrival: list[float],
    cpu_start: float,
    play_start: float,
    peak_rss: float | None,
    values: dict,
) -> dict:
    """Return the case's figures from the arrival times and the node's last diagnostics."""

    def as_int(key: str) -> int | None:
        return int(values[key]) if key in values else None

    n = len(arrivals)
    span = arrivals[-1] - arrivals[0] if n > 1 else 0.0
    gaps_ms = 1000.0 * np.diff(arrivals) if n > 1 else np.empty(0)
    input_span = published[-1] - published[0] if len(published) > 1 else 0.0
    busy = (arrivals[-1] - play_start) if n else 0.0
    cpu = (cpu_at_arrival[-1] - cpu_start) if n else 0.0
    processed = as_int('processed')
    return {
        'images': reliability,
        'play_rate': rate,
        'input_hz': FRAME_RATE * rate,
        'frames_published': len(published),
        'input_frames_per_s': (len(published) - 1) / input_span if input_span > 0 else None,
        'contours_received': n,
        'frames_in': as_int('frames_in'),
        'processed': processed,
        'warming_up': as_int('warming_up'),
        'dropped': {
            k.removeprefix('dropped.'): int(v)
            for k, v in values.items()
            if k.startswith('dropped.')
        },
        'last_frame_ms': float(values['last_frame_ms']) if 'last_frame_ms' in values else None,
        'output_frames_per_s': (n - 1) / span if span > 0 else None,
        'interarrival_ms': (
            {
                'median': float(np.median(gaps_ms)),
                'p90': float(np.percentile(gaps_ms, 90)),
                'max': float(gaps_ms.max()),
            }
            if gaps_ms.size
            else None
        ),
        'node_cpu_pct': 100.0 * cpu / busy if busy > 0 else None,
        'node_cpu_ms_per_frame': 1000.0 * cpu / processed if processed else None,
        'node_peak_rss_mb': peak_rss,
    }


def run_node_benchmark(frames: int = FRAMES, cases=CASES, domain_id: int | None = None) -> dict:
    """Simulate the bag once.

    Then run every (image reliability, play rate) case against a fresh node.
    """
    from memo_ros.core.simulation.imaging import ImagingOptions
    from memo_ros.tools.simulate import simulate

    if domain_id is None:
        domain_id = int(os.environ.get('ROS_DOMAIN_ID') or DEFAULT_DOMAIN_ID)
    os.environ.setdefault(
        'ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST'
    )  # this process's participant too
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    with tempfile.TemporaryDirectory(prefix='memo_ros_bench_node_') as tmp:
        result = simulate(
            SCENARIO,
            Path(tmp) / 'bag',
            frames=frames,
            frame_rate=FRAME_RATE,
            width=SIZE[0],
            height=SIZE[1],
            options=ImagingOptions(),
        )
        rows = [
            run_case(result.bag, reliability, rate, domain_id, env, Path(tmp) / f'node_{k}.log')
            for k, (reliability, rate) in enumerate(cases)
        ]
    return {
        'scenario': SCENARIO,
        'camera': CAMERA,
        'size': f'{SIZE[0]}x{SIZE[1]}',
        'encoding': 'mono8',
        'bag_frames': frames + result.empty_frames,
        'empty_frames': result.empty_frames,
        'background_frames': BACKGROUND_FRAMES,
        'domain_id': domain_id,
        'cases': rows,
    }


def print_node_benchmark(report: dict) -> None:
    """One row per case."""

    def f(value, spec: str = '.1f') -> str:
        return '-' if value is None else format(value, spec)

    print(
        f'contour_node process over DDS: {report["scenario"]} {report["camera"]} {report["size"]} '
        f'{report["encoding"]}, {report["bag_frames"]} frames ({report["empty_frames"]} empty), '
        f'background_frames {report["background_frames"]}, ROS_DOMAIN_ID {report["domain_id"]}'
    )
    print()
    print(
        f'{"images":<12} {"in Hz":>5} {"pub":>4} {"in/s":>5} {"recv":>5} {"f_in":>5} {"proc":>5} '
        f'{"out/s":>6} {"gap med/p90/max ms":>20} {"last ms":>7} {"CPU %":>6} {"CPU ms/f":>8} '
        f'{"RSS MB":>7}  '
        f'dropped'
    )
    for r in report['cases']:
        gaps = r['interarrival_ms']
        gap = '-' if gaps is None else f'{gaps["median"]:.1f}/{gaps["p90"]:.1f}/{gaps["max"]:.1f}'
        dropped = (
            ', '.join(f'{k} {v}' for k, v in r['dropped'].items() if k != 'total' and v) or 'none'
        )
        print(
            f'{r["images"]:<12} {r["input_hz"]:>5.0f} {r["frames_published"]:>4} '
            f'{f(r["input_frames_per_s"]):>5} '
            f'{r["contours_received"]:>5} {f(r["frames_in"], "d"):>5} {f(r["processed"], "d"):>5} '
            f'{f(r["output_frames_per_s"]):>6} {gap:>20} {f(r["last_frame_ms"], ".2f"):>7} '
            f'{f(r["node_cpu_pct"]):>6} {f(r["node_cpu_ms_per_frame"], ".2f"):>8} '
            f'{f(r["node_peak_rss_mb"]):>7}  {dropped}'
        )
    print()
    print(
        "pub = images published, recv = contours received, f_in/proc = the node's "
        'frames_in/processed; '
        'out/s = (recv - 1) / (last - first arrival); CPU = node utime+stime from play start to '
        'the last '
        'arrival; images lost before the node (best effort) show as pub - f_in'
    )
