"""A real person's shoulder width, measured over the first tracked frames.

A body measured from the silhouettes is the template scaled to the person's height, so its
shoulder joints stand where the template's do (380 mm apart at 1.75 m).  People differ more there
than their height says: with the joints 35 mm per side outside a narrow-shouldered dancer's, the
hanging model arms cannot reach the arms in the silhouettes, and in fast arm moves the arms are
lost and the torso turns to make up the width (studio-dance, docs/benchmarks.md: 9 of 16 runs
passed, 13 with the dancer's own 350 mm).

One frame does not tell the width well: refitted at five widths, one frame's misfits scatter by a
few per cent either way, and a template-shaped dancer's width came out 0.88 - 1.09 of the truth.
So every SHOULDER_STRIDE-th tracked frame the tracked pose is refined at each width of
SHOULDER_FACTORS (a few local iterations, the rest of the track untouched) and its misfit per
contour sample added up; after the measuring frames a parabola through the summed misfits gives
the width, kept when it fits MIN_GAIN better than the template's.  It still scatters (the average
adult's 16 runs: 9 kept his width, the rest 334 - 422 mm for 380), but no dancer of the benchmark
lost a run by it and the narrow one passed 12 of 16.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from memo_ros.core.geometry.body import Body

# of the template's shoulder joints' distance from the torso's axis: 334 - 426 mm apart at 1.75 m
SHOULDER_FACTORS = (0.88, 0.94, 1.0, 1.06, 1.12)
# another width must fit this much better than the template's (summed misfit, relative)
MIN_GAIN = 0.02
MEASURE_FRAMES = 30  # tracked frames a real person's width is measured over (tracker_node's)
SHOULDER_STRIDE = 3  # tracked frames between two measurements
REFINE_ITERATIONS = 3  # local relinearisations of the tracked pose at each width
SHOULDERS = ('shoulder_l', 'shoulder_r')


def shoulder_width(body: Body) -> float:
    """Return the distance between the shoulder joint centres across the torso, m."""
    return float(abs(body.joint_offsets['shoulder_l'][1] - body.joint_offsets['shoulder_r'][1]))


def with_shoulder_width(body: Body, factor: float) -> Body:
    """Return ``body`` with its shoulder joints ``factor`` times as far from the torso's axis."""
    if not np.isfinite(factor) or factor <= 0:
        raise ValueError(f'a shoulder width factor must be positive, got {factor}')
    offsets = {j: np.asarray(v, float).copy() for j, v in body.joint_offsets.items()}
    for joint in SHOULDERS:
        offsets[joint][1] *= factor
    return Body(dict(body.shapes), offsets, body.name)


def least_of_parabola(factors: np.ndarray, misfits: np.ndarray, gain: float) -> float:
    """Return where the least-squares parabola through (factors, misfits) is least, or 1.

    Within the factors' range: its vertex when it opens upwards, else the lower end unless the
    vertex (a bulge) lies inside.  1 (the template) unless the parabola there is ``gain``
    (relative) below its value at 1.
    """
    u = np.asarray(factors, float) - 1.0
    a, b, c = np.polyfit(u, misfits, 2)
    lo, hi = float(u.min()), float(u.max())
    if a > 0:
        x = float(np.clip(-b / (2.0 * a), lo, hi))
    elif a < 0 and lo < -b / (2.0 * a) < hi:
        return 1.0  # bulging upwards inside the range: no least to trust
    else:
        x = lo if np.polyval((a, b, c), lo) < np.polyval((a, b, c), hi) else hi
    if np.polyval((a, b, c), x) >= (1.0 - gain) * c:
        return 1.0
    return 1.0 + x


class PoseFitter(Protocol):
    """What the meter needs of a tracker of one width (ArticulatedTracker)."""

    def local_fit(
        self, q: np.ndarray, contours: dict, iterations: int
    ) -> tuple[np.ndarray, float]:
        """Return ``q`` fitted locally to one frame, and its misfit per contour sample."""
        ...


@dataclass
class ShoulderMeter:
    """Sums each width's misfit over the measuring frames of a track (ArticulatedTracker.step)."""

    body: Body  # the template scaled to the person, the widths' base
    frames: int  # tracked frames to measure over
    fitter: Callable[[Body], PoseFitter]  # a tracker of a body, only ever refined
    seen: int = 0  # tracked frames since the start
    measured: int = 0  # frames whose misfits are in the sums
    sums: np.ndarray = field(default_factory=lambda: np.zeros(len(SHOULDER_FACTORS)))
    factor: float | None = None  # the result, once the frames are over
    _fitters: list[PoseFitter] = field(default_factory=list)

    @property
    def widths(self) -> list[float]:
        """Return the widths tried, m."""
        return [shoulder_width(self.body) * f for f in SHOULDER_FACTORS]

    def due(self) -> bool:
        """Count a tracked frame; return whether to measure in it."""
        self.seen += 1
        return self.factor is None and (self.seen - 1) % SHOULDER_STRIDE == 0

    def measure(self, q: np.ndarray, contours: dict[str, np.ndarray]) -> None:
        """Add the misfit of ``q`` refined at each width in this frame."""
        if not self._fitters:
            self._fitters = [
                self.fitter(with_shoulder_width(self.body, f)) for f in SHOULDER_FACTORS
            ]
        misfits = np.array([t.local_fit(q, contours, REFINE_ITERATIONS)[1] for t in self._fitters])
        if np.all(np.isfinite(misfits)):
            self.sums += misfits
            self.measured += 1

    def finished(self) -> bool:
        """Return whether the measuring frames are over; then ``factor`` holds the width's."""
        if self.factor is None and self.seen >= self.frames:
            self.factor = (
                least_of_parabola(np.array(SHOULDER_FACTORS), self.sums, MIN_GAIN)
                if self.measured >= 3
                else 1.0
            )
        return self.factor is not None
