"""A real person's standing height from a start's fit, whatever their posture at that frame.

The visual hull's height (body_estimation.measure_height) is the standing height only while the
person stands upright.  Started at frames 30 and 60 of the Pose2Sim demo (a lunge, a kick, arms
out), it measured the 1.72 m dancer at 1.37 and 1.40 m, and the tracker followed a child-sized
model (IoU 0.38 - 0.47, MPJPE 176 and 443 mm).  The hull's height is a lower bound, so the
start is fitted at it and refitted at heights above it (HEIGHT_STEPS, until the score rises
twice), and the height of least score wins, refined by a parabola through its neighbours.

The score sums two measures of the fit, each relative to its value at the hull's height: the
contour misfit and how much the model's silhouettes and the person's disagree (proportions.py).
The misfit alone favours a smaller model on a real person (fewer of its outline nodes lie off
the silhouette, and nothing counts the person's pixels it leaves uncovered): started at frame 30
of the demo, leaning aside with a leg out, it kept the hull's 1.435 m (1.665 m fitted better by
2 %, under MIN_GAIN) and the live track was turned round in all 70 frames; the disagreement
there is 21 % lower at 1.665 m.  The disagreement alone was flat over 1.71 - 1.80 m for an exact
1.72 m crouch, where the misfit is least at 1.71 m.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from memo_ros.core.geometry.body import Body
from memo_ros.core.geometry.camera import Camera
from memo_ros.core.multiview.body_estimation import scaled_body
from memo_ros.core.multiview.proportions import person_silhouettes, silhouette_disagreement
from memo_ros.core.multiview.tracking import TRACKING, ArticulatedTracker, TrackerSettings

HEIGHT_STEPS = (1.0, 1.08, 1.16, 1.24, 1.32)  # of the hull's height: a deep crouch is 0.76 of it
# a taller body must score this much less than the hull's (relative): the standing Pose2Sim
# dancer's misfit at the hull's height differed by up to 4 % from one 8 % taller
MIN_GAIN = 0.05


@dataclass
class HeightFit:
    """The fitted standing height and what was tried."""

    height: float  # m
    hull_height: float  # m, the lower bound it started from
    # (height m, score: the misfit and the silhouettes' disagreement, each relative to the
    # hull's height's, summed; 2 at the hull's height)
    tried: list[tuple[float, float]] = field(default_factory=list)


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
    (a start's work per height cost the live graph 9 - 15 s), in ascending order until the score
    rises twice in a row; the hull's height stays unless a taller one scores less by MIN_GAIN.
    The score is the contour misfit and the silhouettes' disagreement, each relative to its value
    at the hull's height, summed (module docstring).
    """
    start = ArticulatedTracker(scaled_body(template, hull_height), cameras, settings)
    result = start.step(0, contours)
    if result.status != TRACKING or result.q is None:
        return HeightFit(hull_height, hull_height)
    people = person_silhouettes(start.cameras, contours)
    hull_misfit, hull_disagreement = _measures(start, result.q, contours, people)
    if not people or min(hull_misfit, hull_disagreement) <= 0:
        return HeightFit(hull_height, hull_height)
    tried: list[tuple[float, float]] = [(hull_height, 2.0)]
    for step in HEIGHT_STEPS[1:]:
        # the start's posture and heading, the pelvis raised with the body, refitted
        height = hull_height * step
        tracker = ArticulatedTracker(scaled_body(template, height), cameras, settings)
        q = result.q.copy()
        q[2] *= step
        fitted = tracker.refit(q, contours)
        misfit, disagreement = _measures(tracker, fitted, contours, people)
        tried.append((height, misfit / hull_misfit + disagreement / hull_disagreement))
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


def _measures(
    tracker: ArticulatedTracker, q: np.ndarray, contours: dict[str, np.ndarray], people: dict
) -> tuple[float, float]:
    """Return the contour misfit of ``q`` and its silhouettes' disagreement with ``people``."""
    return (
        float(tracker.misfit(q, contours)),
        float(silhouette_disagreement(tracker.cameras, tracker.body, q, people)),
    )
