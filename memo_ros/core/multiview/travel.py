"""The direction of travel: a walking person faces the way they go.

A cue the silhouettes lack (issue 16): the 14 cylinders look the same turned round with
their sides swapped, but a track that walks backwards at walking pace is far more likely its
own twin than a person walking backwards. The tracker weighs it into the twin's evidence
(tracking.py, ``travel_evidence``).
"""

from __future__ import annotations

from collections import deque

import numpy as np

from memo_ros.core.geometry.rotations import rotvec_to_matrix

TRAVEL_WINDOW_S = 0.5  # the pelvis' displacement over this long is its travel
MIN_SPAN = 0.8  # of the window the path must cover before it says anything


class PelvisPath:
    """The last TRAVEL_WINDOW_S of the tracked pelvis on the floor, to tell its travel."""

    def __init__(self) -> None:
        self._points: deque[tuple[float, float, float]] = deque()

    def add(self, t: float, q: np.ndarray) -> None:
        """Add the pose ``q``'s root (x, y) at time ``t`` (s); older points than the window go."""
        self._points.append((t, float(q[0]), float(q[1])))
        while len(self._points) > 2 and t - self._points[1][0] >= TRAVEL_WINDOW_S:
            self._points.popleft()

    def velocity(self) -> np.ndarray | None:
        """Return the pelvis' mean horizontal velocity (m/s) over the window, None if too short."""
        if len(self._points) < 2:
            return None
        (t0, x0, y0), (t1, x1, y1) = self._points[0], self._points[-1]
        if t1 - t0 < MIN_SPAN * TRAVEL_WINDOW_S:
            return None
        return np.array([x1 - x0, y1 - y0]) / (t1 - t0)


def travel_support(velocity: np.ndarray | None, q: np.ndarray, min_speed: float) -> float:
    """Return how much walking supports the heading of pose ``q``, in [-1, 1].

    The cosine between the torso's forward axis (x) and the travel on the floor, weighted 0 at
    ``min_speed`` rising to 1 at twice it; 0 when slower (standing, dancing on the spot, a step
    aside) or without a path yet.  Negative: the pose walks backwards, its twin forwards.
    """
    if velocity is None or min_speed <= 0:
        return 0.0
    speed = float(np.hypot(*velocity))
    weight = min(max(speed / min_speed - 1.0, 0.0), 1.0)
    if weight == 0.0:
        return 0.0
    forward = rotvec_to_matrix(q[3:6])[:2, 0]
    norm = float(np.hypot(*forward))
    if norm < 1e-6:  # lying along the vertical: no heading to support
        return 0.0
    return weight * float(forward @ velocity) / (norm * speed)
