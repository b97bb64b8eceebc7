"""`benchmark foundation`: the renderer per camera and the simulator's throughput per stage."""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path
import tempfile
import time
from typing import Callable, Iterator

import numpy as np

from memo_ros.tools.benchmarks.report import time_ms

SIM_SCENARIO = 'studio-arm'


SIM_FRAMES = 30


SIM_SIZE = (640, 480)


RENDER_SCALES = (1.0, 0.25)


# simulator stage -> the module-level names of memo_ros.tools.simulate whose calls it counts
SIM_STAGES = {
    'render': ('render',),
    'compose': ('compose_frame',),
    'serialize+write': (
        'convert_encoding',
        'image_msg',
        'camera_info_msg',
        'joint_state_msg',
        'pose_array_msg',
    ),
}


def benchmark_poses(body) -> dict[str, np.ndarray]:
    """Return a walking pose (mid-stride on the studio's arc) and an arm pose.

    Arm raised, elbow bent.
    """
    from memo_ros.core.simulation.scenarios import make_scenario

    walk, _ = make_scenario('studio-walk', body).coordinates(np.array([0.35]))
    arm_scenario = make_scenario('studio-arm', body)
    arm, _ = arm_scenario.coordinates(
        np.array([0.4 * arm_scenario.frames / arm_scenario.frame_rate])
    )
    return {'walk': walk[0], 'arm': arm[0]}


def renderer_times(repeat: int) -> list[dict]:
    """Median and p90 render time (ms) per camera for each pose, resolution and normals setting."""
    from memo_ros.core.geometry.body import load_studio_actor
    from memo_ros.core.geometry.render import render
    from memo_ros.core.simulation.scenarios import studio_cameras

    body = load_studio_actor()
    cameras = studio_cameras(*SIM_SIZE)
    rows = []
    for pose_name, q in benchmark_poses(body).items():
        rotations, origins = body.forward_kinematics(q)
        for scale in RENDER_SCALES:
            for normals in (False, True):
                for cam in cameras:

                    def call(cam=cam, scale=scale, normals=normals):
                        return render(
                            cam,
                            rotations,
                            origins,
                            body.semi_axes,
                            body.lengths,
                            scale=scale,
                            normals=normals,
                        )

                    ms = time_ms(call, repeat)
                    width, height = round(cam.width * scale), round(cam.height * scale)
                    rows.append(
                        {
                            'pose': pose_name,
                            'camera': cam.name,
                            'size': f'{width}x{height}',
                            'normals': normals,
                            'body_pixels': int(np.count_nonzero(call().label)),
                            'median_ms': float(np.median(ms)),
                            'p90_ms': float(np.percentile(ms, 90)),
                        }
                    )
    return rows


@contextmanager
def stage_timer(module, stages: dict[str, tuple[str, ...]]) -> Iterator[dict[str, float]]:
    """Temporarily wrap the named functions of ``module``: their calls add to per-stage seconds."""
    totals = dict.fromkeys(stages, 0.0)
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
    """Temporarily make the module's BagWriter add its write and close time to ``stage``.

    That is the CDR serialization and the mcap writing.
    """
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
    """Frames/s of :func:`simulate` for studio-arm at 640x480 into a temporary bag, by stage."""
    from memo_ros.core.simulation.imaging import ImagingOptions
    import memo_ros.tools.simulate as sim_module

    with tempfile.TemporaryDirectory(prefix='memo_ros_benchmark_') as tmp:
        with (
            stage_timer(sim_module, SIM_STAGES) as totals,
            timed_writer(sim_module, totals, 'serialize+write'),
        ):
            start = time.perf_counter()
            result = sim_module.simulate(
                SIM_SCENARIO,
                Path(tmp) / 'bag',
                frames=frames,
                width=SIM_SIZE[0],
                height=SIM_SIZE[1],
                options=ImagingOptions(),
            )
            wall = time.perf_counter() - start
        bag_bytes = sum(f.stat().st_size for f in (Path(tmp) / 'bag').rglob('*') if f.is_file())
    camera_frames = result.frames * len(result.cameras)
    stages = dict(totals)
    stages['other'] = max(wall - sum(totals.values()), 0.0)
    return {
        'scenario': SIM_SCENARIO,
        'size': f'{SIM_SIZE[0]}x{SIM_SIZE[1]}',
        'frames': result.frames,
        'cameras': len(result.cameras),
        'seconds': wall,
        'frames_per_s': result.frames / wall,
        'camera_frames_per_s': camera_frames / wall,
        'bag_mb': bag_bytes / 1e6,
        'stage_ms_per_camera_frame': {k: 1000.0 * v / camera_frames for k, v in stages.items()},
        'stage_share': {k: v / wall for k, v in stages.items()},
    }


def print_report(report: dict) -> None:
    """One table of the renderer figures, then the simulator's throughput and split."""
    m = report['machine']
    print(f'command  {report["command"]}')
    print(
        f'machine  {m["cpu_count"]} CPUs ({m["cpus_usable"]} usable), {m["processor"]}, Python '
        f'{m["python"]}, '
        f'numpy {m["numpy"]}, OpenCV {m["opencv"]}, {m["platform"]}'
    )
    print()
    print(f'{"renderer, per camera":<42} {"body px":>8} {"median ms":>10} {"p90 ms":>8}')
    for r in report['renderer']:
        case = (
            f'{r["pose"]:<5} {r["camera"]:<10} {r["size"]:>7}{"  normals" if r["normals"] else ""}'
        )
        print(f'{case:<42} {r["body_pixels"]:>8} {r["median_ms"]:>10.2f} {r["p90_ms"]:>8.2f}')
    s = report['simulator']
    print()
    print(
        f'simulate {s["scenario"]} {s["size"]}: {s["frames"]} frames x {s["cameras"]} cameras in '
        f'{s["seconds"]:.2f} s = {s["frames_per_s"]:.1f} frames/s, '
        f'{s["camera_frames_per_s"]:.1f} camera-frames/s, '
        f'bag {s["bag_mb"]:.1f} MB'
    )
    for stage, ms in s['stage_ms_per_camera_frame'].items():
        print(
            f'  {stage:<40} {ms:>8.2f} ms per camera-frame {100 * s["stage_share"][stage]:>5.1f} %'
        )
