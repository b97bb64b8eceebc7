"""A real person's proportions, measured over the first tracked frames: shoulders, upper arms.

A body measured from the silhouettes is the template scaled to the person's height, so its
shoulder joints stand where the template's do (380 mm apart at 1.75 m) and its upper arms are the
template's length (318 mm at 1.75 m).  People differ more there than their height says:
- with the shoulder joints 35 mm per side outside a narrow-shouldered dancer's, the hanging model
  arms cannot reach the arms in the silhouettes, and in fast arm moves the arms are lost and the
  torso turns to make up the width (studio-dance, docs/benchmarks.md: 9 of 16 runs passed, 13
  with the dancer's own 350 mm);
- with upper arms 40 mm longer than the Pose2Sim dancer's (the keypoints' 260 - 279 mm), the
  model's elbows sit below his and the left one bends the wrong way to reach his forearm
  (docs/recordings.md).

Each proportion of PROPORTIONS in turn is measured over ``frames`` tracked frames: every
STRIDE-th, the tracked pose is refined at each size of FACTORS (a few local iterations, the rest of
the track untouched) and scored by how much the model's silhouettes and the person's disagree
(:func:`silhouette_disagreement`); after the frames, a parabola through the summed scores gives the
size, kept when it scores MIN_GAIN better than the template's.  The next proportion is measured on
the body with the sizes found so far.

The score is the silhouettes' disagreement, not the tracker's contour misfit: a smaller model
wins the misfit (fewer of its outline nodes off the silhouette to be pulled, no penalty for
person pixels it leaves uncovered), which took a simulated dancer's true upper arms for 0.88 of
theirs; the disagreement counts a part too short as much as one too long.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from memo_ros.core.geometry.body import Body, PartShape
from memo_ros.core.geometry.camera import Camera
from memo_ros.core.geometry.render import render_body
from memo_ros.core.multiview.body_estimation import silhouette_from_contours

# of the template's size: shoulder joints 334 - 426 mm apart at 1.75 m, upper arms 280 - 356 mm
FACTORS = (0.88, 0.94, 1.0, 1.06, 1.12)
# another size must score this much better than the template's (summed disagreement, relative)
MIN_GAIN = 0.02
SCORE_PX = 320  # silhouettes are compared at most this wide and high (the image resized)
MEASURE_FRAMES = 30  # tracked frames each proportion is measured over (tracker_node's)
STRIDE = 3  # tracked frames between two measurements
REFINE_ITERATIONS = 3  # local relinearisations of the tracked pose at each size
SHOULDERS = ('shoulder_l', 'shoulder_r')
UPPER_ARMS = {'upper_arm_l': 'elbow_l', 'upper_arm_r': 'elbow_r'}  # part: its distal joint


def shoulder_width(body: Body) -> float:
    """Return the distance between the shoulder joint centres across the torso, m."""
    return float(abs(body.joint_offsets['shoulder_l'][1] - body.joint_offsets['shoulder_r'][1]))


def with_shoulder_width(body: Body, factor: float) -> Body:
    """Return ``body`` with its shoulder joints ``factor`` times as far from the torso's axis."""
    _check_factor(factor)
    offsets = {j: np.asarray(v, float).copy() for j, v in body.joint_offsets.items()}
    for joint in SHOULDERS:
        offsets[joint][1] *= factor
    return Body(dict(body.shapes), offsets, body.name)


def upper_arm_length(body: Body) -> float:
    """Return the mean length of the two upper arms (shoulder to elbow joint), m."""
    return float(np.mean([body.joint_offsets[elbow][2] for elbow in UPPER_ARMS.values()]))


def with_upper_arm_length(body: Body, factor: float) -> Body:
    """Return ``body`` with both upper arms ``factor`` times as long, their elbows with them."""
    _check_factor(factor)
    shapes = dict(body.shapes)
    offsets = {j: np.asarray(v, float).copy() for j, v in body.joint_offsets.items()}
    for part, elbow in UPPER_ARMS.items():
        shape = shapes[part]
        shapes[part] = PartShape(shape.length * factor, shape.a, shape.b)
        offsets[elbow][2] *= factor
    return Body(shapes, offsets, body.name)


def _check_factor(factor: float) -> None:
    if not np.isfinite(factor) or factor <= 0:
        raise ValueError(f'a proportion factor must be positive, got {factor}')


@dataclass(frozen=True)
class Proportion:
    """One dimension of the body the tracker measures: its size and the body scaled in it."""

    name: str  # as /diagnostics reports it: body_<name>_m
    size: Callable[[Body], float]  # m
    scaled: Callable[[Body, float], Body]


SHOULDER_WIDTH = Proportion('shoulder_width', shoulder_width, with_shoulder_width)
UPPER_ARM_LENGTH = Proportion('upper_arm_length', upper_arm_length, with_upper_arm_length)
# in the order measured: the width first, since the arms hang from the shoulder joints
PROPORTIONS = (SHOULDER_WIDTH, UPPER_ARM_LENGTH)


def _score_scale(camera: Camera) -> float:
    """Return the resize that brings ``camera``'s image within SCORE_PX across."""
    return min(1.0, SCORE_PX / max(camera.width, camera.height))


def person_silhouettes(
    cameras: dict[str, Camera], contours: dict[str, np.ndarray]
) -> dict[str, np.ndarray]:
    """Return each camera's person mask, what its contours enclose (at most SCORE_PX across)."""
    people = {}
    for name, table in contours.items():
        camera = cameras.get(name)
        if camera is None or not len(table):
            continue
        scale = _score_scale(camera)
        small = camera.scaled(scale)
        people[name] = silhouette_from_contours(table, small.width, small.height, scale)
    return people


def silhouette_disagreement(
    cameras: dict[str, Camera], body: Body, q: np.ndarray, people: dict[str, np.ndarray]
) -> float:
    """Return the pixels where the model's and the person's silhouettes differ, per person pixel.

    Summed over the cameras of ``people`` (:func:`person_silhouettes`); the model's silhouette
    is ``body`` at pose ``q`` rendered at the same size.
    """
    total = 0.0
    for name, person in people.items():
        pixels = np.count_nonzero(person)
        if pixels:
            camera = cameras[name]
            model = render_body(camera, body, q, scale=_score_scale(camera)).label > 0
            total += np.count_nonzero(model ^ person) / pixels
    return total


def least_of_parabola(factors: np.ndarray, scores: np.ndarray, gain: float) -> float:
    """Return where the least-squares parabola through (factors, scores) is least, or 1.

    Within the factors' range: its vertex when it opens upwards, else the lower end unless the
    vertex (a bulge) lies inside.  1 (the template) unless the parabola there is ``gain``
    (relative) below its value at 1.
    """
    u = np.asarray(factors, float) - 1.0
    a, b, c = np.polyfit(u, scores, 2)
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
    """What a meter needs of a tracker of one body (ArticulatedTracker)."""

    body: Body
    cameras: dict[str, Camera]

    def local_fit(self, q: np.ndarray, contours: dict, iterations: int) -> np.ndarray:
        """Return ``q`` fitted locally to one frame."""
        ...


@dataclass
class ProportionMeter:
    """Sums each size's score of one proportion over its measuring frames of a track."""

    proportion: Proportion
    body: Body  # the body before this proportion is measured, the sizes' base
    frames: int  # tracked frames to measure over
    fitter: Callable[[Body], PoseFitter]  # a tracker of a body, only ever refined
    seen: int = 0  # tracked frames since this meter began
    measured: int = 0  # frames whose scores are in the sums
    sums: np.ndarray = field(default_factory=lambda: np.zeros(len(FACTORS)))
    factor: float | None = None  # the result, once the frames are over
    _fitters: list[PoseFitter] = field(default_factory=list)

    @property
    def sizes(self) -> list[float]:
        """Return the sizes tried, m."""
        return [self.proportion.size(self.body) * f for f in FACTORS]

    @property
    def result(self) -> Body:
        """Return the body with the measured size (the base until finished)."""
        if self.factor is None or self.factor == 1.0:
            return self.body
        return self.proportion.scaled(self.body, self.factor)

    def due(self) -> bool:
        """Count a tracked frame; return whether to measure in it."""
        self.seen += 1
        return self.factor is None and (self.seen - 1) % STRIDE == 0

    def measure(self, q: np.ndarray, contours: dict[str, np.ndarray]) -> None:
        """Add the silhouettes' disagreement with ``q`` refined at each size in this frame."""
        if not self._fitters:
            self._fitters = [self.fitter(self.proportion.scaled(self.body, f)) for f in FACTORS]
        people = person_silhouettes(self._fitters[0].cameras, contours)  # the same for every size
        scores = np.array(
            [
                silhouette_disagreement(
                    t.cameras, t.body, t.local_fit(q, contours, REFINE_ITERATIONS), people
                )
                for t in self._fitters
            ]
        )
        if np.all(np.isfinite(scores)) and scores.any():
            self.sums += scores
            self.measured += 1

    def finished(self) -> bool:
        """Return whether the measuring frames are over; then ``factor`` holds the size's."""
        if self.factor is None and self.seen >= self.frames:
            self.factor = (
                least_of_parabola(np.array(FACTORS), self.sums, MIN_GAIN)
                if self.measured >= 3
                else 1.0
            )
            self._fitters = []  # their bodies are of no more use
        return self.factor is not None


@dataclass
class BodyMeter:
    """Measures each proportion in turn over the first tracked frames (ArticulatedTracker.step)."""

    frames: int  # tracked frames per proportion
    fitter: Callable[[Body], PoseFitter]
    proportions: tuple[Proportion, ...] = PROPORTIONS
    done: list[ProportionMeter] = field(default_factory=list)  # the finished meters, in order
    current: ProportionMeter | None = None

    @property
    def finished(self) -> bool:
        """Return whether every proportion is measured."""
        return len(self.done) == len(self.proportions)

    def frame(
        self,
        body: Body,
        q: np.ndarray,
        contours: dict[str, np.ndarray],
        may_measure: Callable[[], bool],
    ) -> Body | None:
        """Count a tracked frame of ``body``, measuring in it if due and ``may_measure()``.

        Return the body to track on with when a proportion's frames end with a size not the
        template's; else None.
        """
        if self.finished:
            return None
        if self.current is None:
            self.current = ProportionMeter(
                self.proportions[len(self.done)], body, self.frames, self.fitter
            )
        meter = self.current
        if meter.due() and may_measure():
            meter.measure(q, contours)
        if not meter.finished():
            return None
        self.done.append(meter)
        self.current = None
        return meter.result if meter.factor != 1.0 else None
