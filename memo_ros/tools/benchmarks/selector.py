"""Per-frame cost of the camera selection (Kakadiaris §4).

14 parts x 3 cameras at the default label resolution.

For every frame of a simulated sequence (the truth as the posterior of t-1), the selector node's
work is timed: the constant-velocity prediction to t, then :meth:`CameraSelector.assign` (one label
rendering per camera, visibility indices, occluding-contour nodes, observability, ranking), and
separately the conversion to the ``/memo/camera_assignment`` message.  Wall-clock milliseconds per
frame: median and 90th percentile.
"""

from __future__ import annotations

import time

import numpy as np

from memo_ros.core.geometry.body import load_studio_actor
from memo_ros.core.multiview.motion import ConstantVelocity
from memo_ros.core.multiview.selection import CameraSelector, SelectionSettings
from memo_ros.core.simulation.scenarios import make_scenario

SCENARIOS = ('studio-arm', 'studio-walk')
SIZE = (640, 480)
TARGET_MS = 5.0


def _time_sequence(scenario_name: str, settings: SelectionSettings, repeat: int) -> dict:
    """Milliseconds per frame of prediction + assignment, and of the message.

    Over ``repeat`` passes.
    """
    from memo_ros.ros.assignment_messages import assignment_to_message

    body = load_studio_actor()
    scenario = make_scenario(scenario_name, body, *SIZE)
    times = np.arange(scenario.frames) / scenario.frame_rate
    q, _ = scenario.coordinates(times)
    qdot = scenario.velocities(times)
    selector = CameraSelector(body, scenario.cameras, settings)
    motion = ConstantVelocity(body)
    dt = 1.0 / scenario.frame_rate
    selector.assign(q[0], q[1])  # warm-up: ray caches
    assign_ms, message_ms, unobserved, per_part = [], [], 0, []
    for _ in range(repeat):
        for k in range(1, len(q)):
            t0 = time.perf_counter()
            q_pred, _ = motion.predict_coordinates(q[k - 1], qdot[k - 1], dt)
            a = selector.assign(q[k - 1], q_pred)
            t1 = time.perf_counter()
            assignment_to_message(a, int(times[k] * 1e9))
            t2 = time.perf_counter()
            assign_ms.append(1000.0 * (t1 - t0))
            message_ms.append(1000.0 * (t2 - t1))
            unobserved += int((~a.observed).sum())
            per_part.append(a.selected.sum(axis=1).mean())
    assign_ms, message_ms = np.asarray(assign_ms), np.asarray(message_ms)
    label = selector._views[0]
    return {
        'scenario': scenario_name,
        'frames': len(assign_ms),
        'cameras': len(scenario.cameras),
        'parts': len(body.lengths),
        'label_size': f'{label.width}x{label.height}',
        'median_ms': float(np.median(assign_ms)),
        'p90_ms': float(np.percentile(assign_ms, 90)),
        'max_ms': float(assign_ms.max()),
        'message_median_ms': float(np.median(message_ms)),
        'cameras_per_part': float(np.mean(per_part)),
        'unobserved_part_frames': unobserved,
    }


def run_selector_benchmark(repeat: int = 3) -> dict:
    """Time the selection per frame on simulated studio sequences at 640x480, default settings."""
    if repeat < 1:
        raise ValueError('repeat must be at least 1')
    settings = SelectionSettings()
    cases = [_time_sequence(name, settings, repeat) for name in SCENARIOS]
    return {
        'size': list(SIZE),
        'render_scale': settings.render_scale,
        'max_cameras_per_part': settings.max_cameras_per_part,
        'observability_norm': settings.observability_norm,
        'repeat': repeat,
        'cases': cases,
        'target_ms': TARGET_MS,
    }


def print_selector_benchmark(report: dict) -> None:
    """One row per scenario: frames, median (p90, max) ms per frame of prediction + assignment."""
    width, height = report['size']
    print(
        f'camera selection per frame, {width}x{height} cameras, render_scale '
        f'{report["render_scale"]}, '
        f'{report["observability_norm"]}, at most {report["max_cameras_per_part"]} cameras per '
        'part; '
        f'target {report["target_ms"]:.0f} ms'
    )
    print(
        f'{"scenario":12} {"frames":>6} {"parts x cams":>12} {"labels":>8} {"median ms":>10} '
        f'{"p90 ms":>8} '
        f'{"max ms":>8} {"message ms":>10} {"cams/part":>9}'
    )
    for c in report['cases']:
        print(
            f'{c["scenario"]:12} {c["frames"]:6d} {c["parts"]:>9d} x{c["cameras"]:<2d} '
            f'{c["label_size"]:>8} '
            f'{c["median_ms"]:10.2f} {c["p90_ms"]:8.2f} {c["max_ms"]:8.2f} '
            f'{c["message_median_ms"]:10.2f} '
            f'{c["cameras_per_part"]:9.2f}'
        )
    print(
        'ms: prediction + assignment (label rendering, VI, contour nodes, observability, '
        'ranking); '
        'message: building the DiagnosticArray'
    )
