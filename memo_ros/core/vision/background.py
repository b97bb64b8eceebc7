"""A background learnt from the sequence itself, for scenes that never show it empty.

A real recording (a person on a treadmill, people in the background) has no
frame without the person, and he covers some pixels most of the time, so the
plain per-pixel median of the frames keeps a "ghost" of him.
:func:`estimate_background` builds the background robustly from the frames:

1. **Still views only:** a pixel's sample of frame k counts only when the
   patch around it (``box`` pixels) is still: it differs by at most ``still``
   grey levels from the frames ``gap`` and 2 ``gap`` before and after.  The
   person (even a torso that only sways) is rarely still for long; the
   background always is.
2. **Masked median:** per pixel, the median over the frames where it is not
   excluded; pixels left with fewer than ``min_seen`` samples have not been
   seen: their value is inpainted from the seen ones around them
   (``cv2.inpaint``).
3. **Person masked out iteratively:** each frame is segmented against that
   background (:func:`compare`); the flagged regions touching the frame's
   motion region (Rohr's change detection against the frames ``gap`` before
   and after, closed into hulls) are the person, grown by ``exclude_margin``
   and excluded too; the median is taken again, ``iterations`` times.
4. **Noise model:** per pixel, the robust spread (1.4826 MAD) of the views
   that showed the background there, floored at the image's noise level.

A person who stands perfectly still longer than the background around him is
visible still remains in it (nothing in one camera's pixels tells them
apart), unless his place is known (``known_person``: a first pass's tracked
body, projected): it is then never learnt from, and pixels that steps 1 and 3
leave unseen (a ring around a person who moves all the time) take the median
of the frames outside that body instead of an inpainted guess.  Live,
:meth:`BackgroundModel.update` keeps learning wherever the caller says the
person is not (outside his grown mask and the tracked body's projection), which
removes such ghosts once he has moved away.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np

from memo_ros.core.vision.change_detection import (
    N_WINDOW,
    ChangeResult,
    Workspace,
    detect_changes,
    projected_energy,
)
from memo_ros.core.vision.cleanup import cleanup

# the motion tests compare the frames nearest this far apart (at least one frame apart): 3 frames
# at 60 frames/s, where they were tuned, and 2 at 30; 3 frames were 150 ms at 20 frames/s, and
# the dancer's ghosts stayed in the Pose2Sim demo's background (its first pass offline: 232 mm
# MPJPE, against 97 with one frame)
MOTION_GAP_S = 0.055
DEFAULT_GAP = 3  # frames, when the frames' times are not known
MAD_TO_SIGMA = 1.4826  # sigma of a normal distribution per unit of median absolute deviation
# sqrt(chi2 quantile 1 - 1e-6 with 6 dof per channel / (channels * n)): under noise alone, the
# summed
# eq. (1) energy of C channels is sigma^2 chi2(6 C); one false pixel per 10^6 above this many
# sigmas
COLOUR_NOISE_FACTOR = {
    1: float(np.sqrt(38.26 / N_WINDOW)),
    3: float(np.sqrt(61.91 / (3 * N_WINDOW))),
}


@dataclass
class BackgroundModel:
    """The learnt background: image, per-pixel noise and how many clean views each pixel had."""

    image: np.ndarray  # (H, W, C) uint8, C = 1 (grey) or 3 (colour, the frames' channel order)
    sigma: np.ndarray  # (H, W) float32: per-pixel noise of a channel, grey levels
    seen: np.ndarray  # (H, W) int32: frames that showed the background here (0: inpainted guess)
    noise: float  # the image's noise level (floor of sigma), grey levels

    @property
    def shape(self) -> tuple[int, int]:
        """Return the background image's (height, width)."""
        return self.image.shape[:2]

    @property
    def unseen(self) -> np.ndarray:
        """Pixels whose background is only a guess from around them (bool (H, W))."""
        return self.seen == 0

    def copy(self) -> 'BackgroundModel':
        """Return an independent copy (the live segmenter updates its model in place)."""
        return BackgroundModel(self.image.copy(), self.sigma.copy(), self.seen.copy(), self.noise)

    def update(
        self,
        frame: np.ndarray,
        background: np.ndarray,
        settled: np.ndarray | None = None,
        wrong: np.ndarray | None = None,
    ) -> None:
        """Learn from ``frame`` where ``background`` (bool (H, W)) says it shows the background.

        There, pixels that have ``settled`` (not changed for several frames) take the frame's value
        when their background is unseen or ``wrong`` (the frame differs from it: a ghost of the
        person, who has left); the other seen pixels move by at most one grey level per frame (a
        running median that follows the lighting, not a limb that passes by).
        """
        frame = as_channels(frame)
        if frame.shape != self.image.shape:
            raise ValueError(
                f'frame {frame.shape} does not match the background {self.image.shape}'
            )
        settled = np.zeros(background.shape, bool) if settled is None else settled
        replace = background & settled & (self.unseen if wrong is None else (self.unseen | wrong))
        drift = background & ~self.unseen & ~replace
        step = np.clip(frame.astype(np.int16) - self.image.astype(np.int16), -1, 1)
        self.image = np.where(drift[..., None], self.image + step, self.image).astype(np.uint8)
        self.image[replace] = frame[replace]
        self.seen[replace | drift] += 1


def as_channels(frame: np.ndarray) -> np.ndarray:
    """Return an image as (H, W, C) uint8 (a grey (H, W) frame gets one channel)."""
    frame = np.asarray(frame)
    if frame.dtype != np.uint8:
        raise ValueError(f'the background model takes uint8 images, got {frame.dtype}')
    return frame[..., None] if frame.ndim == 2 else frame


def largest_channel(image: np.ndarray) -> np.ndarray:
    """Per pixel, the largest of the channels of (..., C): ``image.max(axis=-1)``.

    As C - 1 elementwise maxima, several times faster than numpy's reduction over a short last
    axis (the learning of a background took most of its time there).
    """
    out = image[..., 0].copy()
    for c in range(1, image.shape[-1]):
        np.maximum(out, image[..., c], out=out)
    return out


def grey_of(frame: np.ndarray) -> np.ndarray:
    """Grey levels of an (H, W, C) or (H, W) uint8 image.

    Channel mean for colour: no channel order needed.
    """
    frame = as_channels(frame)
    if frame.shape[2] == 1:
        return np.ascontiguousarray(frame[..., 0])
    return cv2.transform(frame, np.full((1, frame.shape[2]), 1.0 / frame.shape[2]))


# ------------------------------------------------------------------ comparison
def compare(
    frame: np.ndarray,
    model: BackgroundModel,
    threshold: float,
    noise_factor: float | None = None,
    workspace: Workspace | None = None,
) -> ChangeResult:
    """Eq. (1) of every channel of frame - background, each pixel's difference scaled by its noise.

    The channels' energies ||X X* d_c||^2 are summed: a colour change that leaves the grey level
    alone (skin against a beige wall) still counts.  Noisy pixels (edges of the background that
    shimmer) are scaled down to the image's noise level first.  The mask is mean energy per channel
    > n T^2, with T raised to ``noise_factor`` times the image's noise (default: one false pixel
    per 10^6).
    """
    frame = as_channels(frame)
    channels = frame.shape[2]
    if frame.shape != model.image.shape:
        raise ValueError(f'frame {frame.shape} does not match the background {model.image.shape}')
    ws = (workspace or Workspace()).buffers(frame.shape[:2])
    weight = (model.noise / np.maximum(model.sigma, model.noise)).astype(np.float32)
    energy = np.zeros(frame.shape[:2], np.float32)
    square = np.zeros(frame.shape[:2], np.float32)
    for c in range(channels):
        d = cv2.subtract(frame[..., c], model.image[..., c], dtype=cv2.CV_32F)
        d *= weight
        cv2.accumulateSquare(d, square)
        energy += projected_energy(d, ws)
    factor = (
        COLOUR_NOISE_FACTOR.get(channels, COLOUR_NOISE_FACTOR[1])
        if noise_factor is None
        else noise_factor
    )
    applied = max(float(threshold), factor * model.noise)
    mask = energy > np.float32(channels * N_WINDOW * applied**2)  # eq. (1)^2 per channel: > n T^2
    difference = np.sqrt(square / channels)  # RMS difference over the channels
    return ChangeResult(mask, difference, model.noise, applied)


# ------------------------------------------------------------------ learning
def motion_regions(
    grey: np.ndarray,
    gap: int = DEFAULT_GAP,
    grow: int = 9,
    threshold: float = 12.0,
    min_area: int = 50,
) -> np.ndarray:
    """Per frame, where something moves.

    Eq. (1) against the frames ``gap`` before and after, grown, hulled.

    Moving pieces closer than 2 ``grow`` + 1 pixels are joined before their hull is taken, so the
    arms and legs of one person make one region that holds the still torso between them.
    """
    grey = np.asarray(grey)
    count = len(grey)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (4 * grow + 1, 4 * grow + 1))
    regions = np.zeros(grey.shape, bool)
    workspace = Workspace()
    for k in range(count):
        moved = np.zeros(grey.shape[1:], bool)
        for j in (k - gap, k + gap):
            if 0 <= j < count and j != k:
                moved |= detect_changes(grey[k], grey[j], threshold, 1.25, workspace).mask
        grown = cv2.dilate(cleanup(moved).view(np.uint8), kernel)
        regions[k] = convex_regions(grown, min_area)
    return regions


def convex_regions(mask: np.ndarray, min_area: int = 50) -> np.ndarray:
    """Each 8-connected region of at least ``min_area`` pixels replaced by its convex hull.

    A bool image.
    """
    m = np.ascontiguousarray(mask, dtype=bool).view(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    out = np.zeros(m.shape, np.uint8)
    for label in np.flatnonzero(stats[1:, cv2.CC_STAT_AREA] >= min_area) + 1:
        x, y, w, h = (int(v) for v in stats[label, :4])
        points = cv2.findNonZero((labels[y : y + h, x : x + w] == label).view(np.uint8))
        cv2.fillConvexPoly(out, cv2.convexHull(points + np.array([x, y], np.int32)), 1)
    return out.view(bool)


def masked_median(frames: np.ndarray, excluded: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel and channel, the median over the frames where it is not excluded.

    And that count (H, W).
    """
    frames = np.asarray(frames)
    stack = frames.astype(np.uint16)
    stack[excluded] = np.iinfo(np.uint16).max  # sorts after every grey level
    stack.sort(axis=0)
    count = (~excluded).sum(axis=0)
    middle = np.clip((count - 1) // 2, 0, len(frames) - 1)
    index = np.broadcast_to(middle[None, ..., None], (1,) + frames.shape[1:])
    median = np.take_along_axis(stack, index, axis=0)[0]
    return np.where(count[..., None] > 0, median, 0).astype(np.uint8), count.astype(np.int32)


def with_fallback(
    image: np.ndarray,
    count: np.ndarray,
    fallback: np.ndarray,
    fallback_count: np.ndarray,
    min_seen: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Return ``image`` and ``count`` with ``fallback``'s median and count where it was needed.

    That is where ``image`` was seen fewer than ``min_seen`` times and ``fallback`` was not: around
    a person who moves all the time, the motion patches and grown person masks exclude a ring in
    every frame, but the tracked body alone leaves it seen (inpainting would guess it, and flag it
    in every frame).
    """
    use = (count < min_seen) & (fallback_count >= min_seen)
    return np.where(use[..., None], fallback, image), np.where(use, fallback_count, count)


def fill_unseen(image: np.ndarray, unseen: np.ndarray, radius: int = 5) -> np.ndarray:
    """Return the background with its unseen pixels inpainted from the seen ones around them.

    Telea.
    """
    if not unseen.any():
        return image
    if unseen.all():
        return image.copy()
    filled = cv2.inpaint(
        np.ascontiguousarray(image), unseen.view(np.uint8), radius, cv2.INPAINT_TELEA
    )
    return filled.reshape(image.shape)


def person_masks(
    frames: np.ndarray,
    model: BackgroundModel,
    moving: np.ndarray,
    threshold: float,
    min_area: int = 100,
) -> np.ndarray:
    """Per frame, the regions that differ from the background and touch its motion region."""
    masks = np.zeros(frames.shape[:3], bool)
    workspace = Workspace()
    for k, frame in enumerate(frames):
        flagged = cleanup(compare(frame, model, threshold, workspace=workspace).mask)
        n, labels, stats, _ = cv2.connectedComponentsWithStats(
            flagged.view(np.uint8), connectivity=8
        )
        keep = np.zeros(n, bool)
        keep[np.unique(labels[moving[k] & flagged])] = True
        keep &= stats[:, cv2.CC_STAT_AREA] >= min_area
        keep[0] = False
        masks[k] = keep[labels]
    return masks


def noise_level(
    frames: np.ndarray, image: np.ndarray, excluded: np.ndarray
) -> tuple[np.ndarray, float]:
    """Per-pixel robust noise and the image's median of it.

    The noise is 1.4826 MAD of the clean views, of the largest channel.
    """
    deviation = largest_channel(np.abs(frames.astype(np.int16) - image.astype(np.int16))).astype(
        np.uint8
    )
    mad, count = masked_median(deviation[..., None], excluded)
    sigma = MAD_TO_SIGMA * mad[..., 0].astype(np.float32)
    seen = count >= 3
    level = float(np.median(sigma[seen])) if seen.any() else 1.0
    level = max(level, 1.0)  # below one grey level the quantisation dominates
    return np.where(seen, np.maximum(sigma, level), level).astype(np.float32), level


def moving_patches(
    frames: np.ndarray, gap: int = DEFAULT_GAP, box: int = 15, still: float = 6.0
) -> np.ndarray:
    """Per frame.

    Pixels whose ``box``-pixel patch changed by more than ``still`` grey levels (mean of the
    largest channel difference) against the frames ``gap`` and 2 ``gap`` before and after (bool (K,
    H, W)).
    """
    frames = as_channels_stack(frames)
    count = len(frames)
    moving = np.zeros(frames.shape[:3], bool)
    change = np.empty(frames.shape[1:3], np.uint8)
    for k in range(count):
        change.fill(0)
        for j in {min(max(k + d, 0), count - 1) for d in (-2 * gap, -gap, gap, 2 * gap)} - {k}:
            np.maximum(
                change,
                largest_channel(cv2.absdiff(frames[k], frames[j]).reshape(frames.shape[1:])),
                out=change,
            )
        moving[k] = cv2.blur(change.astype(np.float32), (box, box)) > still
    return moving


def as_channels_stack(frames: np.ndarray) -> np.ndarray:
    """Frames as (K, H, W, C) uint8."""
    frames = np.asarray(frames)
    if frames.dtype != np.uint8 or frames.ndim not in (3, 4) or len(frames) < 1:
        raise ValueError(
            f'expected uint8 frames (K, H, W) or (K, H, W, C), got {frames.dtype} {frames.shape}'
        )
    return frames[..., None] if frames.ndim == 3 else frames


def estimate_background(
    frames: np.ndarray,
    threshold: float = 12.0,
    iterations: int = 2,
    min_seen: int = 3,
    gap: int = DEFAULT_GAP,
    box: int = 15,
    still: float = 6.0,
    exclude_margin: int = 4,
    known_person: np.ndarray | None = None,
) -> BackgroundModel:
    """Return the background of a sequence that never shows it empty (see the module docstring).

    From (K, H, W[, C]).

    ``known_person`` (K, H, W) bool: where the person is known to be in each frame (the tracked
    body's projection), never learnt from, however still he stands there.
    """
    frames = as_channels_stack(frames)
    grey = np.stack([grey_of(f) for f in frames])
    if len(frames) > 1:
        moving = moving_patches(frames, gap, box, still)
        person_region = motion_regions(grey, gap)
    else:
        moving = person_region = np.zeros(grey.shape, bool)
    known_view = None
    if known_person is not None:
        known_person = np.asarray(known_person, bool)
        moving = moving | known_person
        known_view = masked_median(frames, known_person)
    excluded = moving
    kernel = cv2.getStructuringElement(
        cv2.MORPH_ELLIPSE, (2 * exclude_margin + 1, 2 * exclude_margin + 1)
    )
    model = None
    for iteration in range(max(int(iterations), 0) + 1):
        image, count = masked_median(frames, excluded)
        if known_view is not None:
            image, count = with_fallback(image, count, *known_view, min_seen)
        unseen = count < min_seen
        sigma, level = noise_level(frames, image, excluded)
        model = BackgroundModel(
            fill_unseen(image, unseen), sigma, np.where(unseen, 0, count).astype(np.int32), level
        )
        if iteration == iterations:
            break
        person = person_masks(frames, model, person_region, threshold)
        excluded = moving | np.stack(
            [cv2.dilate(p.view(np.uint8), kernel).view(bool) for p in person]
        )
    if model is None:  # the loop above runs at least once
        raise AssertionError('no background model estimated')
    return model


# ------------------------------------------------------------------ live segmenter
class SequenceSegmenter:
    """Raw person mask against a background learnt from the first frames of the sequence.

    Then kept learning.

    The first ``learn_frames`` frames are buffered and :func:`estimate_background` runs on them
    (the last of them is already segmented); afterwards :meth:`learn` is told, frame by frame,
    where the person is (the kept regions and the tracked body's projection) and updates the model
    everywhere else.
    """

    def __init__(
        self,
        threshold: float = 12.0,
        learn_frames: int = 30,
        noise_factor: float | None = None,
        learn_margin: int = 6,
        still_sigmas: float = 4.0,
        settle_frames: int = 5,
    ) -> None:
        """T of eq. (1) in grey levels; frames learnt from.

        Noise floor (None: one false pixel per 10^6); margin kept around the person (or the tracked
        body) when learning later frames, pixels; a pixel has settled when it changed by at most
        ``still_sigmas`` noise sigmas in each of the last ``settle_frames`` frames.
        """
        if learn_frames < 1:
            raise ValueError(f'learn_frames must be at least 1, got {learn_frames}')
        self.threshold = float(threshold)
        self.learn_frames = int(learn_frames)
        self.noise_factor = noise_factor
        self.learn_margin = int(learn_margin)
        self.still_sigmas = float(still_sigmas)
        self.settle_frames = int(settle_frames)
        self.workspace = Workspace()
        self.reset()

    @property
    def warming_up(self) -> bool:
        """True while the first frames are being gathered."""
        return self.model is None

    @property
    def unseen(self) -> np.ndarray | None:
        """Pixels whose background is still a guess (bool (H, W)), None before the model exists."""
        return None if self.model is None else self.model.unseen

    def reset(self) -> None:
        """Forget the model and learn again from the next frames."""
        self.model: BackgroundModel | None = None
        self._frames: list[np.ndarray] = []
        self._stamps: list[int | None] = []  # the gathered frames' times, ns (None: not known)
        self._previous: np.ndarray | None = None
        self._still_run: np.ndarray | None = None
        self._flagged: np.ndarray | None = None

    def set_model(self, model: BackgroundModel) -> None:
        """Use a given background model instead of learning one.

        For example one estimated offline from the whole sequence.
        """
        self.model = model
        self._frames, self._stamps = [], []

    def segment(self, image: np.ndarray, stamp_ns: int | None = None) -> ChangeResult | None:
        """Eq. (1) of the frame against the background (raw mask, difference, noise).

        None while gathering.  ``stamp_ns``: the frame's time; with every gathered frame's, the
        motion tests compare frames :func:`motion_gap` apart (about 55 ms), not DEFAULT_GAP.
        """
        frame = as_channels(np.asarray(image))
        if self.model is not None and self.model.image.shape != frame.shape:
            self.reset()  # another image size: start over
        if self.model is None:
            self._frames.append(frame.copy())
            self._stamps.append(stamp_ns)
            if len(self._frames) < self.learn_frames:
                return None
            self.model = estimate_background(
                np.stack(self._frames), self.threshold, gap=motion_gap(self._stamps)
            )
            self._frames, self._stamps = [], []
        result = compare(frame, self.model, self.threshold, self.noise_factor, self.workspace)
        self._flagged = result.mask.copy()
        return result

    def learn(self, image: np.ndarray, person: np.ndarray, roi: np.ndarray | None = None) -> None:
        """Update the model from a segmented frame.

        Outside the grown tracked body ``roi`` when it is known (a ghost stuck to the person's
        regions is learnt away there), else outside the grown person mask.
        """
        if self.model is None:
            return
        frame = as_channels(np.asarray(image))
        occupied = person if roi is None else roi
        size = 2 * self.learn_margin + 1
        grown = cv2.dilate(
            occupied.view(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
        )
        if (
            self._previous is None
            or self._previous.shape != frame.shape
            or self._still_run is None  # never: learn() sets it with _previous
        ):
            self._still_run = np.zeros(frame.shape[:2], np.int16)
        else:
            change = largest_channel(cv2.absdiff(frame, self._previous).reshape(frame.shape))
            still = change <= self.still_sigmas * self.model.noise
            self._still_run = np.where(
                still, np.minimum(self._still_run + 1, self.settle_frames), 0
            )
        self._previous = frame.copy()
        settled = self._still_run >= self.settle_frames
        self.model.update(frame, grown == 0, settled, self._flagged)


# ------------------------------------------------------------------ images
def evenly_spaced(count: int, most: int) -> np.ndarray:
    """Return indices of at most ``most`` items spread evenly over ``count``.

    All of them when there are fewer.
    """
    if count <= most:
        return np.arange(count)
    return np.unique(np.round(np.linspace(0, count - 1, most)).astype(int))


def motion_gap(stamps_ns: Sequence[int | None]) -> int:
    """Return how many frames apart the motion tests compare: the nearest to MOTION_GAP_S.

    At least one, from the frames' median spacing in time; DEFAULT_GAP without two stamps or
    when a frame's is not known (None).
    """
    if any(s is None for s in stamps_ns):
        return DEFAULT_GAP
    steps = np.diff(np.asarray(stamps_ns, np.int64))
    steps = steps[steps > 0]
    if not len(steps):
        return DEFAULT_GAP
    return max(1, round(MOTION_GAP_S / (float(np.median(steps)) * 1e-9)))


def background_from_frames(
    frames: list[np.ndarray],
    most: int,
    threshold: float = 12.0,
    person_at: Callable[[int], np.ndarray] | None = None,
    stamps_ns: Sequence[int] | None = None,
) -> BackgroundModel:
    """:func:`estimate_background` of at most ``most`` frames spread evenly over a recording.

    ``person_at(i)``: where the person is known to be in frame i (bool (H, W)), e.g. the tracked
    body of a first pass over the recording, asked for the frames learnt from only.
    ``stamps_ns``: the frames' times, which set the motion tests' gap (:func:`motion_gap`).
    """
    if not frames:
        raise ValueError('no frames to learn the background from')
    chosen = evenly_spaced(len(frames), most)
    known = None if person_at is None else np.stack([person_at(int(i)) for i in chosen])
    gap = DEFAULT_GAP if stamps_ns is None else motion_gap([stamps_ns[i] for i in chosen])
    return estimate_background(
        np.stack([frames[i] for i in chosen]), threshold, gap=gap, known_person=known
    )
