"""Per-frame cost of the articulated tracker's update.

14 parts, the studio's 3 cameras, 200 / 1,000 / 5,000 contour points each; then 1,000 points each
from 3, 4, 6 and 8 cameras (``--cameras``) on a ring around the studio, and the cost of each added
camera: the least-squares slope of the medians over the camera counts.

The contours are perfect silhouettes of the simulated studio-arm sequence, resampled so every
camera has the wanted number of samples; each frame is one :meth:`ArticulatedTracker.step`
(prediction, the candidates' outline tests, force assignment and the iterated EKF update), timed in
this process by the wall clock and by the thread's CPU time (on a shared machine the CPU time is
the steadier of the two: it leaves out the time other processes held the core).  The nodes run
numpy's BLAS on one thread (memo_ros/nodes/__init__.py); this command keeps the environment's
setting, so ``OPENBLAS_NUM_THREADS=1`` measures what the tracker node does on one core, and the
report says which it was.
"""

from __future__ import annotations

import os
import time

import numpy as np

from memo_ros.core.geometry.body import load_studio_actor
from memo_ros.core.geometry.camera import Camera
from memo_ros.core.geometry.render import render
from memo_ros.core.multiview.tracking import ArticulatedTracker, TrackerSettings
from memo_ros.core.simulation.scenarios import make_scenario
from memo_ros.core.simulation.scenarios import ring_cameras as studio_ring
from memo_ros.core.vision.contours import (
    occluding_contours,
    perimeter,
    silhouette_outlines,
)

POINTS_PER_CAMERA = (200, 1000, 5000)
RING_CAMERAS = (3, 4, 6, 8)
RING_POINTS = 1000
FRAMES = 30
TARGET_MS = 10.0  # at 1,000 points per camera


def parse_cameras(text: str) -> tuple[int, ...]:
    """'3,4,6,8' -> (3, 4, 6, 8); ValueError unless whole numbers from 1 to 64."""
    try:
        counts = tuple(int(word) for word in text.split(',') if word.strip())
    except ValueError:
        raise ValueError(f'cameras must be whole numbers, comma separated, not {text!r}') from None
    if not counts or any(not 1 <= n <= 64 for n in counts):
        raise ValueError(f'camera counts must be from 1 to 64, not {text!r}')
    return counts


def per_camera_slope(cameras: list[int], ms: list[float]) -> float | None:
    """Milliseconds each added camera costs: the least-squares line through (cameras, ms).

    None with fewer than two different camera counts.
    """
    if len(set(cameras)) < 2:
        return None
    return float(np.polyfit(np.asarray(cameras, float), np.asarray(ms, float), 1)[0])


def _outlines(cameras, body, q) -> dict[str, list[np.ndarray]]:
    rotations, origins = body.forward_kinematics(q)
    out = {}
    for cam in cameras:
        out[cam.name] = silhouette_outlines(
            render(cam, rotations, origins, body.semi_axes, body.lengths).label > 0
        )
    return out


def _resampled(outlines: list[np.ndarray], count: int) -> np.ndarray:
    """Contour samples of the outlines with about ``count`` samples in all."""
    length = sum(perimeter(o) for o in outlines)
    return occluding_contours(outlines, step=max(length / count, 0.05), smoothing=2.0)


def ring_cameras(count: int, width: int = 640, height: int = 480) -> list[Camera]:
    """``count`` cameras evenly round the studio, 4 m out, at heights from 1.2 to 2.5 m."""
    k = np.arange(count)
    azimuths = np.degrees(2 * np.pi * k / count + 0.3)
    return studio_ring(azimuths, 4.0, 1.2 + 1.3 * (k % 3) / 2, width, height)


def _timed_steps(
    body, cameras, q, times, frames, repeat, settings
) -> tuple[np.ndarray, np.ndarray, list]:
    """Wall-clock and CPU milliseconds of each frame after the first, and its iterations."""
    ms, cpu_ms, iterations = [], [], []
    for _ in range(repeat):
        tracker = ArticulatedTracker(
            body, cameras, settings or TrackerSettings(), initial_pose=q[0]
        )
        tracker.step(0, frames[0])  # initialisation frame, not timed
        for k in range(1, len(frames)):
            t0, c0 = time.perf_counter(), time.thread_time()
            result = tracker.step(int(times[k] * 1e9), frames[k])
            ms.append(1000.0 * (time.perf_counter() - t0))
            cpu_ms.append(1000.0 * (time.thread_time() - c0))
            iterations.append(result.report.iterations)
    return np.asarray(ms), np.asarray(cpu_ms), iterations


def _case(frames, ms, cpu_ms, iterations, cameras: int, count: int, rig: str) -> dict:
    return {
        'rig': rig,
        'cameras': cameras,
        'points_per_camera': count,
        'points_actual': int(np.mean([sum(len(t) for t in f.values()) for f in frames]) / cameras),
        'frames': len(ms),
        'median_ms': float(np.median(ms)),
        'p90_ms': float(np.percentile(ms, 90)),
        'cpu_median_ms': float(np.median(cpu_ms)),
        'iterations_mean': float(np.mean(iterations)),
    }


def run_tracker_benchmark(
    repeat: int = 1,
    settings: TrackerSettings | None = None,
    cameras: tuple[int, ...] = RING_CAMERAS,
    frames: int = FRAMES,
    densities: tuple[int, ...] = POINTS_PER_CAMERA,
) -> dict:
    """Milliseconds per tracker step per density and camera count: median and p90.

    ``densities``: points per camera from the studio's 3 cameras; ``cameras``: camera counts
    on the ring, 1,000 points each.
    """
    body = load_studio_actor()
    scenario = make_scenario('studio-arm', body, frames=frames)
    times = np.arange(frames) / scenario.frame_rate
    q, _ = scenario.coordinates(times)
    outlines = [_outlines(scenario.cameras, body, q[k]) for k in range(frames)]
    cases = []
    for count in densities:
        tables = [{cam: _resampled(o, count) for cam, o in frame.items()} for frame in outlines]
        timed = _timed_steps(body, scenario.cameras, q, times, tables, repeat, settings)
        cases.append(_case(tables, *timed, len(scenario.cameras), count, 'studio'))
    for n in cameras:
        rig = ring_cameras(n)
        tables = [
            {cam: _resampled(o, RING_POINTS) for cam, o in _outlines(rig, body, q[k]).items()}
            for k in range(frames)
        ]
        timed = _timed_steps(body, rig, q, times, tables, repeat, settings)
        cases.append(_case(tables, *timed, n, RING_POINTS, 'ring'))
    ring = [c for c in cases if c['rig'] == 'ring']
    counts = [c['cameras'] for c in ring]
    return {
        'parts': len(body.lengths),
        'cases': cases,
        'ms_per_camera': per_camera_slope(counts, [c['median_ms'] for c in ring]),
        'cpu_ms_per_camera': per_camera_slope(counts, [c['cpu_median_ms'] for c in ring]),
        'target_ms': TARGET_MS,
        'blas_threads': os.environ.get('OPENBLAS_NUM_THREADS', 'default'),
    }


def print_tracker_benchmark(report: dict) -> None:
    """One row per camera count and contour density, then the cost per added camera."""
    settings = ', '.join(f'{k}={v}' for k, v in report.get('tracker', {}).items())
    print(
        f'tracker update per frame, TrackerSettings({settings}), {report["parts"]} parts, BLAS '
        f'threads {report["blas_threads"]}; target {report["target_ms"]:.0f} ms at 1,000 points '
        'per camera from 3 cameras (studio) and from 6 (ring)'
    )
    print(
        f'{"rig":6} {"cameras":>7} {"points/camera":>13} {"frames":>6} {"median ms":>10} '
        f'{"p90 ms":>8} {"CPU ms":>8} {"iterations":>10}'
    )
    for c in report['cases']:
        print(
            f'{c["rig"]:6} {c["cameras"]:>7} {c["points_actual"]:>13} {c["frames"]:>6} '
            f'{c["median_ms"]:>10.2f} {c["p90_ms"]:>8.2f} {c["cpu_median_ms"]:>8.2f} '
            f'{c["iterations_mean"]:>10.1f}'
        )
    print('median and p90: wall clock; CPU ms: median CPU time of the thread')
    if report['ms_per_camera'] is not None:
        counts = ', '.join(str(c['cameras']) for c in report['cases'] if c['rig'] == 'ring')
        print(
            f'each added camera (1,000 points) costs {report["ms_per_camera"]:.2f} ms '
            f'({report["cpu_ms_per_camera"]:.2f} ms of CPU): least-squares slope of the ring '
            f'medians over {counts} cameras'
        )
