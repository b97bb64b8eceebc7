"""Rohr's binary cleanup of a change mask (Rohr §4.1).

"Detected image points having a small number of neighbors in a 3x3 window are deleted and
nondetected points with a large number of neighbors are marked", repeated until stable; then
the remaining holes are filled.  Both the segmenters and the sequence background use it.
"""

from __future__ import annotations

import cv2
import numpy as np


def cleanup(
    mask: np.ndarray,
    delete_below: int = 3,
    fill_above: int = 5,
    max_iterations: int = 10,
    fill_holes: bool = True,
) -> np.ndarray:
    """Rohr's binary cleanup.

    Delete sparse points, mark dense gaps, repeat until stable, fill holes (bool).
    """
    # Neighbours are the 8 pixels of the 3x3 window (outside the image counts as unflagged).  Every
    # iteration updates all pixels at once from the previous iteration's counts.  A flag can only
    # spread one pixel per iteration, so after the first (full-frame) iteration the work is done in
    # the bounding box of the surviving flags grown by the remaining iteration count.
    m = np.ascontiguousarray(mask, dtype=bool).view(np.uint8)
    height, width = m.shape
    if not m.any():
        return np.zeros((height, width), bool)
    out = np.zeros((height, width), np.uint8)
    x, y, w, h = 0, 0, width, height
    current = m
    for iteration in range(max(int(max_iterations), 0)):
        updated = _cleanup_step(current, delete_below, fill_above)
        stable = np.array_equal(updated, current)
        current = updated
        if stable or not current.any():
            break
        if iteration == 0:  # shrink to the flags' box: they grow <= 1 px per iteration
            bx, by, bw, bh = cv2.boundingRect(current)
            grow = max(int(max_iterations) - 1, 0) + 1
            x0, y0 = max(x + bx - grow, 0), max(y + by - grow, 0)
            x1, y1 = min(x + bx + bw + grow, width), min(y + by + bh + grow, height)
            current = np.ascontiguousarray(current[y0 - y : y1 - y, x0 - x : x1 - x])
            x, y, w, h = x0, y0, x1 - x0, y1 - y0
    # pixels at the image edge see "outside" as unflagged only when the ROI touches that edge;
    # elsewhere the ROI's zero surround is the true neighbourhood, so the ROI result is exact
    if fill_holes:
        current = _fill_holes(current)
    out[y : y + h, x : x + w] = current
    return out.view(bool)


def _cleanup_step(m: np.ndarray, delete_below: int, fill_above: int) -> np.ndarray:
    """One parallel update.

    Keep flagged pixels with >= k1 flagged neighbours, add unflagged with > k2.
    """
    total = cv2.boxFilter(
        m, -1, (3, 3), normalize=False, borderType=cv2.BORDER_CONSTANT
    )  # 3x3 sum incl. self
    neighbours = cv2.subtract(total, m)
    keep = cv2.bitwise_and(m, (neighbours >= delete_below).view(np.uint8))
    add = (neighbours > fill_above).view(np.uint8)
    return cv2.bitwise_or(keep, add)


def _fill_holes(m: np.ndarray) -> np.ndarray:
    """Mark unflagged regions not connected to the border of ``m`` (0/1 uint8 in and out)."""
    padded = cv2.copyMakeBorder(m, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
    cv2.floodFill(padded, None, (0, 0), 2)  # the outside, via the zero frame: 2
    return (padded[1:-1, 1:-1] != 2).view(np.uint8)  # flags (1) and holes (0) -> 1
