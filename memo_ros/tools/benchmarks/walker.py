"""Cost of Rohr's walker per frame.

Initialization and tracking, ours against the paper's exhaustive grid.

A street-walk (640x480, default noise) is simulated once and its frames go through the contour
pipeline (not timed); then the walker runs over the sequence ``repeat`` times from scratch.  Per
frame: wall-clock and CPU milliseconds (one core: OpenCV single-threaded, numpy without threads),
model evaluations (grid points scored, s(p) of eq. 11) and visibility renderings.  The paper's
exhaustive grid renders every grid point: its cost is the measured time of one full model
evaluation (rendering, hidden-contour removal, similarity) times the grid's size, 21 x 11 x 21
points in tracking (2 dX = 40 cm, 2 dY = 20 cm, 2 dpose = 0.4 in 2 cm and 0.02 steps) and 21 x 11 x
50 per initialization image (whole cycle).
"""

from __future__ import annotations

from pathlib import Path
import tempfile
import time

import numpy as np

SIZE = (640, 480)
FULL_EVALUATION_SAMPLES = 40
PAPER_TRACKING_GRID = 21 * 11 * 21
PAPER_INIT_GRID = 21 * 11 * 50


def _frames(bag: Path, studio) -> list[tuple[int, np.ndarray | None, np.ndarray]]:
    """(stamp, rectangle corners or None, edge lines) of every frame.

    As contour_node would publish them.
    """
    from memo_ros.core.vision.contours import ContourPipeline
    from memo_ros.nodes.contour_node import pipeline_settings
    from memo_ros.ros.bagio import grey_images

    camera = studio.cameras[0]
    pipeline = ContourPipeline(pipeline_settings(studio.node_parameters.get('contour_node', {})))
    frames = []
    for stamp, grey in grey_images(bag, f'/{camera.name}/image_raw'):
        out = pipeline.process(grey)
        corners = None
        if out.box is not None:
            x, y, w, h = out.box
            corners = np.array([[x, y], [x + w, y], [x + w, y + h], [x, y + h]], float)
        frames.append((stamp, corners, out.edges))
    return frames


def _full_evaluation_ms(studio, frames) -> float:
    """Median ms of one model evaluation as the paper's grid needs it.

    Render, hidden contours, s(p).
    """
    from memo_ros.core.walking.search import WalkerModel
    from memo_ros.core.walking.similarity import candidate_edges, edge_table, similarity

    body, camera = studio.body, studio.cameras[0]
    model = WalkerModel(body, camera, reuse_distance=0.0)
    rng = np.random.default_rng(0)
    edges = edge_table(next(e for _, c, e in frames[len(frames) // 2 :] if len(e)))
    times = []
    for _ in range(FULL_EVALUATION_SAMPLES):
        pose, X = rng.uniform(0, 1), rng.uniform(-0.2, 0.2)
        start = time.perf_counter()
        contours = model.contours(X, 0.0, 0.0, pose)
        a, b = contours.project(camera)
        pairs = candidate_edges(a[0], b[0], edges, 0.0, model.params)
        similarity(a, b, edges, *pairs, model.params)
        times.append(time.perf_counter() - start)
    return 1000.0 * float(np.median(times))


def run_walker_benchmark(repeat: int = 2) -> dict:
    """Measure the walker over a simulated street-walk ``repeat`` times."""
    import cv2

    from memo_ros.core.formats.studio import Studio
    from memo_ros.core.simulation.imaging import ImagingOptions
    from memo_ros.core.walking.tracker import WalkingTracker
    from memo_ros.tools.simulate import simulate

    cv2.setNumThreads(1)
    with tempfile.TemporaryDirectory(prefix='memo_ros_bench_walker_') as tmp:
        result = simulate(
            'street-walk',
            Path(tmp) / 'street',
            width=SIZE[0],
            height=SIZE[1],
            options=ImagingOptions(),
        )
        studio = Studio.load(result.studio)
        frames = _frames(result.bag, studio)
    rows = {'initialization': [], 'tracking': []}
    totals = {
        'initialization': [0.0, 0.0, 0, 0, 0],
        'tracking': [0.0, 0.0, 0, 0, 0],
    }  # wall, cpu, evals, rend, n
    for _ in range(repeat):
        tracker = WalkingTracker(studio.body, studio.cameras[0])
        for stamp, corners, edges in frames:
            wall, cpu = time.perf_counter(), time.process_time()
            step = tracker.step(stamp, corners, edges)
            wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
            phase = (
                'initialization'
                if step.event in ('init_image', 'init_skipped', 'started')
                else 'tracking'
                if step.event == 'tracked'
                else None
            )
            if phase is None:
                continue
            t = totals[phase]
            t[0] += wall
            t[1] += cpu
            t[2] += step.evaluations
            t[3] += step.renderings
            t[4] += 1
            if phase == 'tracking':
                rows[phase].append((1000 * wall, 1000 * cpu, step.evaluations, step.renderings))
    tracking = np.array(rows['tracking'])
    init = totals['initialization']
    full_ms = _full_evaluation_ms(studio, frames)
    return {
        'scenario': 'street-walk',
        'size': f'{SIZE[0]}x{SIZE[1]}',
        'frames': len(frames),
        'repeat': repeat,
        'init_images_per_run': init[4] // repeat,
        'init_ms_per_image': 1000 * init[0] / max(init[4], 1),
        'init_cpu_ms_per_image': 1000 * init[1] / max(init[4], 1),
        'init_evaluations_per_image': init[2] / max(init[4], 1),
        'init_renderings_per_image': init[3] / max(init[4], 1),
        'tracking_frames_per_run': len(tracking) // repeat,
        'tracking_ms_median': float(np.median(tracking[:, 0])),
        'tracking_ms_p90': float(np.percentile(tracking[:, 0], 90)),
        'tracking_ms_max': float(tracking[:, 0].max()),
        'tracking_cpu_ms_median': float(np.median(tracking[:, 1])),
        'tracking_cpu_ms_p90': float(np.percentile(tracking[:, 1], 90)),
        'tracking_evaluations_median': float(np.median(tracking[:, 2])),
        'tracking_renderings_mean': float(tracking[:, 3].mean()),
        'full_evaluation_ms': full_ms,
        'paper_tracking_evaluations': PAPER_TRACKING_GRID,
        'paper_tracking_ms': full_ms * PAPER_TRACKING_GRID,
        'paper_init_evaluations': PAPER_INIT_GRID,
        'paper_init_ms': full_ms * PAPER_INIT_GRID,
    }


def print_walker_benchmark(report: dict) -> None:
    """Return the figures as a small table."""
    r = report
    print(
        f'walker on {r["scenario"]} {r["size"]}, {r["frames"]} frames, {r["repeat"]} passes, one '
        'core'
    )
    print(f'{"phase":<30} {"ms/frame":>10} {"CPU ms":>8} {"evaluations":>12} {"renderings":>11}')
    print(
        f'{"initialization (per image)":<30} {r["init_ms_per_image"]:>10.1f} '
        f'{r["init_cpu_ms_per_image"]:>8.1f} '
        f'{r["init_evaluations_per_image"]:>12.0f} {r["init_renderings_per_image"]:>11.1f}'
    )
    print(
        f'{"tracking median":<30} {r["tracking_ms_median"]:>10.1f} '
        f'{r["tracking_cpu_ms_median"]:>8.1f} '
        f'{r["tracking_evaluations_median"]:>12.0f} {r["tracking_renderings_mean"]:>11.1f}'
    )
    print(
        f'{"tracking p90 / max":<30} {r["tracking_ms_p90"]:>10.1f} '
        f'{r["tracking_cpu_ms_p90"]:>8.1f}   '
        f'(max {r["tracking_ms_max"]:.1f} ms)'
    )
    print(
        f"paper's exhaustive grid: one full evaluation (render + hidden contours + s(p)) "
        f'{r["full_evaluation_ms"]:.2f} ms'
    )
    print(
        f'{"  tracking, 21 x 11 x 21 grid":<30} {r["paper_tracking_ms"]:>10.0f} ms/frame '
        f'({r["paper_tracking_evaluations"]} evaluations)'
    )
    print(
        f'{"  initialization, 21 x 11 x 50":<30} {r["paper_init_ms"]:>10.0f} ms/image '
        f'({r["paper_init_evaluations"]} evaluations)'
    )
    print(
        f'target: tracking under 40 ms per frame (25 frames/s): median '
        f'{"meets" if r["tracking_ms_median"] < 40 else "misses"} it, p90 '
        f'{"meets" if r["tracking_ms_p90"] < 40 else "misses"} it'
    )
