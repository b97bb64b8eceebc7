"""Scoring a track without ground truth: how well the projected model covers the segmented person.

For a real recording nothing says where the joints truly were, but every
camera says where the person is: the silhouette IoU between the model
rendered into a camera and the person segmented in that camera's image is
1 when they coincide and drops with every pixel of the person the model
misses or of the background it covers.  Frames lost after the track started
are the other half of the verdict.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

TRACKED = 'tracking'


def silhouette_iou(model: np.ndarray, person: np.ndarray) -> float:
    """Intersection over union of two bool masks (NaN when both are empty)."""
    model, person = np.asarray(model, bool), np.asarray(person, bool)
    union = int(np.count_nonzero(model | person))
    return float(np.count_nonzero(model & person)) / union if union else float('nan')


@dataclass
class LostFrames:
    """What became of the frames after the first tracked one."""

    first_tracked: int | None  # index of the first tracked frame, None when none was
    after_start: int  # frames after it
    lost: int  # of those, not tracked (any outcome but tracking, or never reported)
    reasons: dict[str, int]  # outcome -> count among the lost ones


def lost_after_start(outcomes: list[str | None]) -> LostFrames:
    """Frames not tracked after the first tracked one, from each frame's outcome in order.

    None: no report.
    """
    first = next((k for k, o in enumerate(outcomes) if o == TRACKED), None)
    if first is None:
        return LostFrames(None, 0, 0, {})
    rest = outcomes[first + 1 :]
    reasons = Counter('unreported' if o is None else o for o in rest if o != TRACKED)
    return LostFrames(first, len(rest), sum(reasons.values()), dict(sorted(reasons.items())))


def iou_summary(iou: np.ndarray, cameras: list[str]) -> dict[str, dict[str, float | int]]:
    """Per camera (columns of ``iou``, frames in rows, NaN where not scored).

    Frames, mean, median, min.
    """
    summary = {}
    for c, name in enumerate(cameras):
        values = iou[:, c][np.isfinite(iou[:, c])]
        summary[name] = {
            'frames': int(len(values)),
            'mean': float(values.mean()) if len(values) else float('nan'),
            'median': float(np.median(values)) if len(values) else float('nan'),
            'min': float(values.min()) if len(values) else float('nan'),
        }
    return summary
