"""Measure the speed of the core and tools and print the figures (no pass/fail).

``memo-ros benchmark foundation`` times the renderer per camera (studio
cameras, full and quarter resolution, with and without normals, a walking and
an arm pose) and the simulator's throughput with its per-stage split.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shlex
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from memo_ros.tools import bench_graph

SUITES = ('foundation', 'contours', 'contour-node', 'selector', 'tracker', 'walker', 'graph')
SIM_SCENARIO = 'studio-arm'
SIM_FRAMES = 30
SIM_SIZE = (640, 480)
RENDER_SCALES = (1.0, 0.25)
# simulator stage -> the module-level names of memo_ros.tools.simulate whose calls it counts
SIM_STAGES = {
    'render': ('render',),
    'compose': ('compose_frame',),
    'serialize+write': ('convert_encoding', 'image_msg', 'camera_info_msg', 'joint_state_msg', 'pose_array_msg'),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('suite', choices=SUITES, help='what to measure: foundation = renderer and simulator; '
                        'contours = the contour pipeline per 640x480 frame, one OpenCV thread; '
                        'contour-node = the contour_node process fed at 30 and 60 Hz over DDS; '
                        'selector = camera assignment per frame, 14 parts x 3 cameras (--repeat: passes over '
                        'each sequence); tracker = the articulated EKF update per frame at 200, 1,000 and '
                        '5,000 contour points per camera (--repeat: passes over the sequence); walker = Rohr\'s walker per '
                        'frame on a street-walk, initialization and tracking, against the paper\'s exhaustive grid '
                        '(--repeat: passes over the sequence); graph = the whole live graph (3 contour nodes, '
                        'selector, tracker) fed a 3-camera 640x480 bag at 30 and 60 Hz: latency per stage and end '
                        'to end, rates, drops, CPU and memory per process')
    parser.add_argument('--repeat', type=int, default=20, help='timed repetitions per renderer case (default 20)')
    parser.add_argument('--json', action='store_true', help='print one JSON object instead of the table')
    bench_graph.add_arguments(parser)


def run(args: argparse.Namespace) -> int:
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
    """(measure(args) -> dict, print(report)) of a benchmark suite; the node suites import lazily."""
    if name == 'contours':
        from memo_ros.tools.bench_contours import print_contour_benchmark, run_contour_benchmark
        return (lambda args: run_contour_benchmark(repeat=args.repeat)), _with_command(print_contour_benchmark)
    if name == 'selector':
        from memo_ros.tools.bench_selector import print_selector_benchmark, run_selector_benchmark
        return (lambda args: run_selector_benchmark(repeat=args.repeat)), _with_command(print_selector_benchmark)
    if name == 'tracker':
        from memo_ros.tools.bench_tracker import print_tracker_benchmark, run_tracker_benchmark
        return (lambda args: run_tracker_benchmark(repeat=args.repeat)), _with_command(print_tracker_benchmark)
    if name == 'walker':
        from memo_ros.tools.bench_walker import print_walker_benchmark, run_walker_benchmark
        return (lambda args: run_walker_benchmark(repeat=args.repeat)), _with_command(print_walker_benchmark)
    if name == 'graph':
        return bench_graph.measure, _with_command(bench_graph.print_graph_benchmark)
    if name == 'contour-node':
        from memo_ros.tools.bench_contour_node import print_node_benchmark, run_node_benchmark
        return (lambda args: run_node_benchmark()), _with_command(print_node_benchmark)
    return (lambda args: {'renderer': renderer_times(args.repeat), 'simulator': simulator_throughput()},
            print_report)


def _with_command(show):
    """A report printer that first prints the command line that produced the report."""
    def printer(report: dict) -> None:
        print(f"command  {report['command']}")
        show(report)
    return printer


def command_line(args: argparse.Namespace) -> str:
    """The command line that reproduces this run."""
    if args.suite == 'graph':
        options = bench_graph.command_words(args)
    else:
        options = [] if args.suite == 'contour-node' else ['--repeat', str(args.repeat)]   # that suite has no repeats
    words = ['memo-ros', 'benchmark', args.suite, *options] + (['--json'] if args.json else [])
    return shlex.join(words)


def machine() -> dict:
    """Where the figures were measured: CPUs, Python, numpy and OpenCV versions."""
    import cv2
    usable = len(os.sched_getaffinity(0)) if hasattr(os, 'sched_getaffinity') else os.cpu_count()
    return {'cpu_count': os.cpu_count(), 'cpus_usable': usable, 'processor': platform.processor() or platform.machine(),
            'python': platform.python_version(), 'numpy': np.__version__, 'opencv': cv2.__version__,
            'platform': platform.platform()}


# ---------------------------------------------------------------- renderer
def benchmark_poses(body) -> dict[str, np.ndarray]:
    """A walking pose (mid-stride on the studio's arc) and an arm pose (arm raised, elbow bent)."""
    from memo_ros.core.scenarios import make_scenario
    walk, _ = make_scenario('studio-walk', body).coordinates(np.array([0.35]))
    arm_scenario = make_scenario('studio-arm', body)
    arm, _ = arm_scenario.coordinates(np.array([0.4 * arm_scenario.frames / arm_scenario.frame_rate]))
    return {'walk': walk[0], 'arm': arm[0]}


def _time_ms(call: Callable[[], object], repeat: int) -> np.ndarray:
    """Wall-clock milliseconds of ``repeat`` calls, after one untimed warm-up call (ray caches)."""
    call()
    times = np.empty(repeat)
    for k in range(repeat):
        start = time.perf_counter()
        call()
        times[k] = time.perf_counter() - start
    return 1000.0 * times


def renderer_times(repeat: int) -> list[dict]:
    """Median and p90 render time (ms) per camera for each pose, resolution and normals setting."""
    from memo_ros.core.body import load_default_body
    from memo_ros.core.render import render
    from memo_ros.core.scenarios import studio_cameras
    body = load_default_body()
    cameras = studio_cameras(*SIM_SIZE)
    rows = []
    for pose_name, q in benchmark_poses(body).items():
        rotations, origins = body.forward_kinematics(q)
        for scale in RENDER_SCALES:
            for normals in (False, True):
                for cam in cameras:
                    def call(cam=cam, scale=scale, normals=normals):
                        return render(cam, rotations, origins, body.semi_axes, body.lengths, scale=scale,
                                      normals=normals)
                    ms = _time_ms(call, repeat)
                    width, height = round(cam.width * scale), round(cam.height * scale)
                    rows.append({'pose': pose_name, 'camera': cam.name, 'size': f'{width}x{height}',
                                 'normals': normals, 'body_pixels': int(np.count_nonzero(call().label)),
                                 'median_ms': float(np.median(ms)), 'p90_ms': float(np.percentile(ms, 90))})
    return rows


# --------------------------------------------------------------- simulator
@contextmanager
def stage_timer(module, stages: dict[str, tuple[str, ...]]) -> Iterator[dict[str, float]]:
    """Temporarily wrap the named functions of ``module`` so their calls add to per-stage seconds."""
    totals = {stage: 0.0 for stage in stages}
    originals = {}

    def timed(stage: str, function: Callable) -> Callable:
        def wrapper(*args, **kwargs):
            start = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                totals[stage] += time.perf_counter() - start
        return wrapper

    try:
        for stage, names in stages.items():
            for name in names:
                originals[name] = getattr(module, name)
                setattr(module, name, timed(stage, originals[name]))
        yield totals
    finally:
        for name, function in originals.items():
            setattr(module, name, function)


@contextmanager
def timed_writer(module, totals: dict[str, float], stage: str) -> Iterator[None]:
    """Temporarily make the module's BagWriter add its write and close time (CDR, mcap) to ``stage``."""
    original = module.BagWriter

    class TimedWriter(original):
        def write(self, *args, **kwargs) -> None:
            start = time.perf_counter()
            super().write(*args, **kwargs)
            totals[stage] += time.perf_counter() - start

        def close(self) -> None:
            start = time.perf_counter()
            super().close()
            totals[stage] += time.perf_counter() - start

    module.BagWriter = TimedWriter
    try:
        yield
    finally:
        module.BagWriter = original


def simulator_throughput(frames: int = SIM_FRAMES) -> dict:
    """Frames/s of :func:`simulate` for studio-arm at 640x480 into a temporary bag, split by stage."""
    import memo_ros.tools.simulate as sim_module
    from memo_ros.core.imaging import ImagingOptions
    with tempfile.TemporaryDirectory(prefix='memo_ros_benchmark_') as tmp:
        with stage_timer(sim_module, SIM_STAGES) as totals, timed_writer(sim_module, totals, 'serialize+write'):
            start = time.perf_counter()
            result = sim_module.simulate(SIM_SCENARIO, Path(tmp) / 'bag', frames=frames, width=SIM_SIZE[0],
                                         height=SIM_SIZE[1], options=ImagingOptions())
            wall = time.perf_counter() - start
        bag_bytes = sum(f.stat().st_size for f in (Path(tmp) / 'bag').rglob('*') if f.is_file())
    camera_frames = result.frames * len(result.cameras)
    stages = {stage: seconds for stage, seconds in totals.items()}
    stages['other'] = max(wall - sum(totals.values()), 0.0)
    return {'scenario': SIM_SCENARIO, 'size': f'{SIM_SIZE[0]}x{SIM_SIZE[1]}', 'frames': result.frames,
            'cameras': len(result.cameras), 'seconds': wall, 'frames_per_s': result.frames / wall,
            'camera_frames_per_s': camera_frames / wall, 'bag_mb': bag_bytes / 1e6,
            'stage_ms_per_camera_frame': {k: 1000.0 * v / camera_frames for k, v in stages.items()},
            'stage_share': {k: v / wall for k, v in stages.items()}}


# ------------------------------------------------------------------ report
def print_report(report: dict) -> None:
    """One table of the renderer figures, then the simulator's throughput and split."""
    m = report['machine']
    print(f'command  {report["command"]}')
    print(f'machine  {m["cpu_count"]} CPUs ({m["cpus_usable"]} usable), {m["processor"]}, Python {m["python"]}, '
          f'numpy {m["numpy"]}, OpenCV {m["opencv"]}, {m["platform"]}')
    print()
    print(f'{"renderer, per camera":<42} {"body px":>8} {"median ms":>10} {"p90 ms":>8}')
    for r in report['renderer']:
        case = f'{r["pose"]:<5} {r["camera"]:<10} {r["size"]:>7}{"  normals" if r["normals"] else ""}'
        print(f'{case:<42} {r["body_pixels"]:>8} {r["median_ms"]:>10.2f} {r["p90_ms"]:>8.2f}')
    s = report['simulator']
    print()
    print(f'simulate {s["scenario"]} {s["size"]}: {s["frames"]} frames x {s["cameras"]} cameras in '
          f'{s["seconds"]:.2f} s = {s["frames_per_s"]:.1f} frames/s, {s["camera_frames_per_s"]:.1f} camera-frames/s, '
          f'bag {s["bag_mb"]:.1f} MB')
    for stage, ms in s['stage_ms_per_camera_frame'].items():
        print(f'  {stage:<40} {ms:>8.2f} ms per camera-frame {100 * s["stage_share"][stage]:>5.1f} %')
