"""A real person's standing height from a start's fit, whatever their posture at that frame.

The visual hull's height (body_estimation.measure_height) is the standing height only while the
person stands upright.  Started at frames 30 and 60 of the Pose2Sim demo (a lunge, a kick, arms
out), it measured the 1.72 m dancer at 1.37 and 1.40 m, and the tracker followed a child-sized
model (IoU 0.38 - 0.47, MPJPE 176 and 443 mm).  The hull's height is a lower bound, so the
start is fitted at it and refitted at heights above it (HEIGHT_STEPS, until the misfit rises
twice), and the height of least misfit per contour sample wins, refined by a parabola through
its neighbours: a body too small leaves the outline's extremes unmatched, one too large cannot
fold into it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from memo_ros.core.geometry.body import Body
from memo_ros.core.geometry.camera import Camera
from memo_ros.core.multiview.body_estimation import scaled_body
from memo_ros.core.multiview.tracking import TRACKING, ArticulatedTracker, TrackerSettings

HEIGHT_STEPS = (1.0, 1.08, 1.16, 1.24, 1.32)  # of the hull's height: a deep crouch is 0.76 of it
# a taller body must fit this much better than the hull's (misfit per sample, relative): a start
# at the hull's height of the standing Pose2Sim dancer differed by up to 4 % from one 8 % taller
MIN_GAIN = 0.05


@dataclass
class HeightFit:
    """The fitted standing height and what was tried."""

    height: float  # m
    hull_height: float  # m, the lower bound it started from
    tried: list[tuple[float, float]] = field(default_factory=list)  # (height m, misfit)


def fit_height(
    template: Body,
    cameras: list[Camera],
    contours: dict[str, np.ndarray],
    hull_height: float,
    settings: TrackerSettings | None = None,
) -> HeightFit:
    """Return the standing height at which a start from the silhouettes fits ``contours`` best.

    A start from the silhouettes alone at ``hull_height``; then ``template`` scaled to
    ``hull_height`` times each further step of HEIGHT_STEPS, its pose refitted from the start's
    (a start's work per height cost the live graph 9 - 15 s), in ascending order until the
    misfit rises twice in a row; the hull's height stays unless a taller one fits better by
    MIN_GAIN.
    """
    tried: list[tuple[float, float]] = []
    start = ArticulatedTracker(scaled_body(template, hull_height), cameras, settings)
    result = start.step(0, contours)
    if result.status != TRACKING or result.q is None:
        return HeightFit(hull_height, hull_height)
    tried.append((hull_height, start.misfit(result.q, contours)))
    for step in HEIGHT_STEPS[1:]:
        # the start's posture and heading, the pelvis raised with the body, refitted
        height = hull_height * step
        tracker = ArticulatedTracker(scaled_body(template, height), cameras, settings)
        q = result.q.copy()
        q[2] *= step
        tried.append((height, tracker.misfit(tracker.refit(q, contours), contours)))
        if len(tried) > 2 and tried[-1][1] > tried[-2][1] > tried[-3][1]:
            break  # rising twice: past the least (once may be one fit gone wrong)
    best = int(np.argmin([m for _, m in tried]))
    if tried[best][1] > (1.0 - MIN_GAIN) * tried[0][1]:
        return HeightFit(hull_height, hull_height, tried)
    if best == len(tried) - 1:
        return HeightFit(tried[best][0], hull_height, tried)
    (h0, m0), (h1, m1), (h2, m2) = tried[best - 1 : best + 2]
    curvature = m0 - 2 * m1 + m2  # > 0: m1 is the least of the three
    offset = 0.5 * (m0 - m2) / curvature if curvature > 0 else 0.0
    return HeightFit(h1 + float(np.clip(offset, -1.0, 1.0)) * (h2 - h1), hull_height, tried)
