"""Per-frame cost of the articulated tracker's update.

14 parts, 3 cameras, 200 / 1,000 / 5,000 contour points each; then 1,000 points each from 4, 6
and 8 cameras on a ring around the studio (how the update grows with the cameras).

The contours are perfect silhouettes of the simulated studio-arm sequence, resampled so every
camera has the wanted number of samples; each frame is one :meth:`ArticulatedTracker.step`
(prediction, the candidates' outline tests, force assignment and the iterated EKF update), timed in
this process.  The nodes run numpy's BLAS on one thread (memo_ros/nodes/__init__.py); this command
keeps the environment's setting, so ``OPENBLAS_NUM_THREADS=1`` measures what the tracker node does
on one core, and the report says which it was.
"""

from __future__ import annotations

import os
import time

import numpy as np

from memo_ros.core.geometry.body import load_default_body
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
RING_CAMERAS = (4, 6, 8)
RING_POINTS = 1000
FRAMES = 30
TARGET_MS = 10.0  # at 1,000 points per camera


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


def _timed_steps(body, cameras, q, times, frames, repeat, settings) -> tuple[np.ndarray, list]:
    """Milliseconds of each tracked frame after the first, and the iterations each took."""
    ms, iterations = [], []
    for _ in range(repeat):
        tracker = ArticulatedTracker(
            body, cameras, settings or TrackerSettings(), initial_pose=q[0]
        )
        tracker.step(0, frames[0])  # initialisation frame, not timed
        for k in range(1, len(frames)):
            t0 = time.perf_counter()
            result = tracker.step(int(times[k] * 1e9), frames[k])
            ms.append(1000.0 * (time.perf_counter() - t0))
            iterations.append(result.report.iterations)
    return np.asarray(ms), iterations


def _case(frames, ms, iterations, cameras: int, count: int) -> dict:
    return {
        'cameras': cameras,
        'points_per_camera': count,
        'points_actual': int(np.mean([sum(len(t) for t in f.values()) for f in frames]) / cameras),
        'frames': len(ms),
        'median_ms': float(np.median(ms)),
        'p90_ms': float(np.percentile(ms, 90)),
        'iterations_mean': float(np.mean(iterations)),
    }


def run_tracker_benchmark(repeat: int = 1, settings: TrackerSettings | None = None) -> dict:
    """Milliseconds per tracker step per density and camera count: median and p90."""
    body = load_default_body()
    scenario = make_scenario('studio-arm', body, frames=FRAMES)
    times = np.arange(FRAMES) / scenario.frame_rate
    q, _ = scenario.coordinates(times)
    outlines = [_outlines(scenario.cameras, body, q[k]) for k in range(FRAMES)]
    cases = []
    for count in POINTS_PER_CAMERA:
        frames = [{cam: _resampled(o, count) for cam, o in frame.items()} for frame in outlines]
        ms, iterations = _timed_steps(body, scenario.cameras, q, times, frames, repeat, settings)
        cases.append(_case(frames, ms, iterations, len(scenario.cameras), count))
    for n in RING_CAMERAS:
        cameras = ring_cameras(n)
        frames = [
            {cam: _resampled(o, RING_POINTS) for cam, o in _outlines(cameras, body, q[k]).items()}
            for k in range(FRAMES)
        ]
        ms, iterations = _timed_steps(body, cameras, q, times, frames, repeat, settings)
        cases.append(_case(frames, ms, iterations, n, RING_POINTS))
    return {
        'parts': len(body.lengths),
        'cases': cases,
        'target_ms': TARGET_MS,
        'blas_threads': os.environ.get('OPENBLAS_NUM_THREADS', 'default'),
    }


def print_tracker_benchmark(report: dict) -> None:
    """One row per camera count and contour density."""
    print(
        f'tracker update per frame, {report["parts"]} parts, BLAS threads '
        f'{report["blas_threads"]}; target {report["target_ms"]:.0f} ms at 1,000 points per '
        'camera from 3 cameras (studio) and from 6 (ring)'
    )
    print(
        f'{"cameras":>7} {"points/camera":>13} {"frames":>6} {"median ms":>10} {"p90 ms":>8} '
        f'{"iterations":>10}'
    )
    for c in report['cases']:
        print(
            f'{c["cameras"]:>7} {c["points_actual"]:>13} {c["frames"]:>6} '
            f'{c["median_ms"]:>10.2f} {c["p90_ms"]:>8.2f} {c["iterations_mean"]:>10.1f}'
        )
