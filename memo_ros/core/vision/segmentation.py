"""Person segmentation.

Raw change masks, Rohr's binary cleanup, regions with rectangle and outline.

Two segmenters give a raw boolean mask of "person" pixels:

- :class:`ChangeSegmenter`: Rohr §4.1, eq. (1) against the previous frame
  (:class:`~memo_ros.core.vision.change_detection.ChangeDetector`).  It sees what
  moves: the moving person and the background they just uncovered.
- :class:`BackgroundSegmenter`: a static background learnt as the per-pixel
  median of the first N frames, then eq. (1) between each frame and that
  background.  It sees a person who stands still, as long as every pixel shows
  the background in more than half of the learning frames (an empty studio at
  start, or a person walking through).
- :class:`~memo_ros.core.vision.background.SequenceSegmenter` ('sequence'): for
  recordings that never show the scene empty: the background of the first N
  frames with the person masked out (motion regions, then his own masks), in
  colour, with a per-pixel noise model, and learnt further from every later
  frame outside the person and the tracked body.

Both feed the same :func:`cleanup` (Rohr §4.1: "detected image points having a small number of
neighbors in a 3x3 window are deleted and nondetected points with a large number of neighbors are
marked", repeated until stable, then the remaining holes filled) and :func:`select_regions`
(enclosing rectangle and outline of each kept region, Rohr Figs. 10-11).  ``keep='tracked'`` keeps
the regions that overlap a prior (the tracked body's projection, else the previous frame's person
grown), so people in the background are not taken for him.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from memo_ros.core.vision.background import SequenceSegmenter
from memo_ros.core.vision.change_detection import (
    NOISE_FACTOR,
    ChangeDetector,
    ChangeResult,
    Workspace,
    detect_changes,
)
from memo_ros.core.vision.cleanup import cleanup

SEGMENTERS = ('background', 'change', 'sequence')
KEEP_MODES = ('largest', 'all', 'tracked')
_EMPTY_OUTLINE = np.zeros((0, 2), np.int32)
# grey levels: a pixel differing by less is unchanged even in noise-free frames (uint8 steps)
PIXEL_FLOOR = 0.5
# cleanup k2 for exact frames: fill pinholes only (a 1 px slit's closed end has 7 neighbours)
EXACT_FILL_ABOVE = 7
# a window larger than this share of the frame is not worth it: the whole frame is segmented
WINDOW_MOST = 0.6


# ------------------------------------------------------------------ regions
@dataclass
class Region:
    """One kept connected region: its pixel count, enclosing rectangle and outer outline."""

    area: int
    box: tuple[int, int, int, int]  # x, y, w, h in pixels (Rohr's enclosing rectangle)
    outline: np.ndarray  # (N, 2) int32 pixel coordinates (x, y), cv2.findContours order


def select_regions(
    mask: np.ndarray, min_area: int = 200, keep: str = 'largest', prior: np.ndarray | None = None
) -> tuple[np.ndarray, list[Region]]:
    """Keep the largest, every.

    Or (``'tracked'``) every region overlapping ``prior`` among the 8-connected regions of at least
    ``min_area`` pixels: kept mask, regions. 'tracked' without a prior, or when no region overlaps
    it, keeps the largest.
    """
    if keep not in KEEP_MODES:
        raise ValueError(f'keep must be one of {", ".join(KEEP_MODES)}, got {keep!r}')
    m = np.ascontiguousarray(mask, dtype=bool).view(np.uint8)
    kept = np.zeros(m.shape, bool)
    if not m.any():
        return kept, []
    bx, by, bw, bh = cv2.boundingRect(m)  # label only the flags' box
    roi = m[by : by + bh, bx : bx + bw]
    n, labels, stats, _ = cv2.connectedComponentsWithStats(roi, connectivity=8, ltype=cv2.CV_32S)
    areas = stats[1:, cv2.CC_STAT_AREA]
    candidates = np.flatnonzero(areas >= min_area) + 1
    if candidates.size == 0:
        return kept, []
    if keep == 'tracked' and prior is not None:
        overlap = np.bincount(labels[prior[by : by + bh, bx : bx + bw]], minlength=n)
        consistent = candidates[overlap[candidates] > 0]
        candidates = consistent if consistent.size else candidates
        keep = 'all' if consistent.size else 'largest'
    if keep != 'all':
        candidates = candidates[[int(np.argmax(areas[candidates - 1]))]]
    else:
        candidates = candidates[np.argsort(-areas[candidates - 1], kind='stable')]
    regions = []
    for label in candidates:
        x, y, w, h = (int(v) for v in stats[label, :4])
        region = labels[y : y + h, x : x + w] == label
        kept[by + y : by + y + h, bx + x : bx + x + w] |= region
        contours, _ = cv2.findContours(
            region.view(np.uint8),
            cv2.RETR_EXTERNAL,
            cv2.CHAIN_APPROX_NONE,
            offset=(bx + x, by + y),
        )
        outline = max(contours, key=len).reshape(-1, 2) if contours else _EMPTY_OUTLINE
        regions.append(
            Region(int(stats[label, cv2.CC_STAT_AREA]), (bx + x, by + y, w, h), outline)
        )
    return kept, regions


def union_box(regions: list[Region]) -> tuple[int, int, int, int] | None:
    """Return the rectangle (x, y, w, h) enclosing every region, None without regions."""
    if not regions:
        return None
    boxes = np.array([r.box for r in regions])
    x0, y0 = boxes[:, 0].min(), boxes[:, 1].min()
    x1, y1 = (boxes[:, 0] + boxes[:, 2]).max(), (boxes[:, 1] + boxes[:, 3]).max()
    return int(x0), int(y0), int(x1 - x0), int(y1 - y0)


# -------------------------------------------------------------- segmenters
class ChangeSegmenter:
    """Raw person mask from Rohr's change detection against the previous frame (eq. 1, j = k-1)."""

    def __init__(self, threshold: float = 12.0, noise_factor: float = NOISE_FACTOR) -> None:
        """``threshold``.

        T of eq. (1), grey levels, raised to ``noise_factor`` noise sigmas (0: fixed T).
        """
        self.detector = ChangeDetector(threshold, noise_factor)

    @property
    def warming_up(self) -> bool:
        """True until a previous frame exists."""
        return self.detector.previous is None

    def reset(self) -> None:
        """Forget the previous frame."""
        self.detector.reset()

    def segment(self, grey: np.ndarray) -> ChangeResult | None:
        """Eq. (1) against the previous frame (raw mask, difference, noise).

        None without a previous frame.
        """
        return self.detector.detect(grey)


class BackgroundSegmenter:
    """Raw person mask.

    Eq. (1) between the frame and a static background (median of the first N frames).
    """

    def __init__(
        self,
        threshold: float = 4.0,
        learn_frames: int = 10,
        noise_factor: float = NOISE_FACTOR,
        compensate_gain: bool = True,
    ) -> None:
        """T of eq. (1) against the background; N learning frames; noise floor.

        Global gain compensation.
        """
        if learn_frames < 1:
            raise ValueError(f'learn_frames must be at least 1, got {learn_frames}')
        self.threshold = float(threshold)
        self.learn_frames = int(learn_frames)
        self.noise_factor = float(noise_factor)
        self.compensate_gain = bool(compensate_gain)
        self.workspace = Workspace()
        self.window_workspace = Workspace()  # a window's buffers, of its own size
        self.gain = 1.0
        self.reset()

    @property
    def warming_up(self) -> bool:
        """True while the background is still being learnt."""
        return self.background is None

    def reset(self) -> None:
        """Forget the background and learn it again from the next N frames."""
        self.background: np.ndarray | None = None
        self.moved_pixels = 0  # see moved_pixels(): 0 for a given background
        self._scaled: np.ndarray | None = None
        self._learning: np.ndarray | None = None
        self._count = 0

    def set_background(self, background: np.ndarray) -> None:
        """Use a given background (e.g. a picture of the empty studio) instead of learning one."""
        self.background = np.ascontiguousarray(background, np.uint8).copy()
        self.moved_pixels = 0
        self._scaled = None
        self._learning, self._count = None, 0

    def _reference(
        self, background: np.ndarray, grey: np.ndarray, view: tuple[slice, slice] | None = None
    ) -> np.ndarray:
        """Return the background (its ``view``, if given).

        Scaled by the whole frame's global gain (slow lighting changes) when that is on.
        """
        part = background if view is None else background[view]
        if not self.compensate_gain:
            return part
        sample_bg = background[::8, ::8].astype(np.float32)
        sample = grey[::8, ::8].astype(np.float32)
        valid = sample_bg > 16.0
        gain = float(np.median(sample[valid] / sample_bg[valid])) if valid.any() else 1.0
        self.gain = gain
        if abs(gain - 1.0) < 0.005:  # below half a grey level at mid grey: no rescaling
            return part
        if self._scaled is None or self._scaled.shape != part.shape:
            self._scaled = np.empty(part.shape, np.float32)
        # OpenCV takes a scalar factor; its stubs admit only arrays (opencv-python#1008)
        return cv2.multiply(  # type: ignore[call-overload]
            part, gain, dst=self._scaled, dtype=cv2.CV_32F
        )

    def segment(
        self,
        grey: np.ndarray,
        window: tuple[int, int, int, int] | None = None,
        sigma: float | None = None,
    ) -> ChangeResult | None:
        """Eq. (1) against the background (raw mask, difference, noise), None while learning.

        ``window`` (x, y, w, h): only there (the result is the window's size), with the noise
        ``sigma`` of an earlier whole frame.
        """
        grey = np.asarray(grey)
        if self.background is not None and self.background.shape == grey.shape:
            view = None if window is None else _slices(window)
            reference = self._reference(self.background, grey, view)
            frame = grey if view is None else grey[view]
            frame = frame if reference.dtype == frame.dtype else frame.astype(np.float32)
            return detect_changes(
                frame,
                reference,
                self.threshold,
                self.noise_factor,
                self.workspace if view is None else self.window_workspace,
                sigma,
            )
        if self._learning is None or self._learning.shape[1:] != grey.shape:
            self._learning = np.empty((self.learn_frames,) + grey.shape, np.uint8)
            self._count = 0
        self._learning[self._count] = grey
        self._count += 1
        if self._count == self.learn_frames:
            # per-pixel median: a person covering a pixel in fewer than half the frames is voted
            # out
            self.background = np.median(self._learning, axis=0).round().astype(np.uint8)
            self.moved_pixels = moved_pixels(self._learning, self.background)
            self._learning = None
        return None


def moved_pixels(
    frames: np.ndarray, background: np.ndarray, change: float = 20.0, min_area: int = 50
) -> int:
    """Pixels where something moved while the background was learnt (its largest frame's count).

    A frame's pixels that differ from the learnt median by more than ``change`` grey levels, in
    regions of at least ``min_area`` pixels: a person in view moves and so shows here, and the
    parts of him that stood still are in the median.
    """
    most = 0
    for frame in frames:
        moved = (cv2.absdiff(frame, background) > change).view(np.uint8)
        n, _, stats, _ = cv2.connectedComponentsWithStats(moved, connectivity=8)
        areas = stats[1:, cv2.CC_STAT_AREA]
        most = max(most, int(areas[areas >= min_area].sum()))
    return most


def refine_boundary(
    raw: np.ndarray,
    filled: np.ndarray,
    difference: np.ndarray,
    pixel_threshold: float,
    depth: int = 2,
) -> np.ndarray:
    """Undo eq. (1)'s 2 px spread.

    Keep the filled core, and near its edge only pixels whose own |d| is large.
    """
    # The 5x5 fit flags pixels up to 2 px outside a strong step edge; the core (filled mask eroded
    # by
    # ``depth``) lies inside, the band around it is decided per pixel: raw flag and |g_k - g_j| >
    # t.
    size = 2 * depth + 1
    core = cv2.erode(
        filled.view(np.uint8),
        cv2.getStructuringElement(cv2.MORPH_RECT, (size, size)),
        borderType=cv2.BORDER_CONSTANT,
        borderValue=0,
    )
    strong = _compare_scalar(_absolute(difference), float(pixel_threshold), cv2.CMP_GT)  # 0 / 255
    band = cv2.bitwise_and(
        cv2.bitwise_and(raw.view(np.uint8), filled.view(np.uint8)), strong
    )  # 0 / 1
    return cv2.bitwise_or(core, band).view(bool)


def carve_background_channels(
    mask: np.ndarray, difference: np.ndarray, pixel_threshold: float
) -> np.ndarray:
    """Remove from ``mask`` the unchanged pixels (|d| <= t) that connect 4-wise to the outside.

    Bool.
    """
    # The 5x5 fit of eq. (1) spreads 2 px from either side of a gap, so a slit up to 4 px wide (an
    # arm
    # hanging next to the trunk) is flagged in full and is no band pixel of refine_boundary.  Where
    # the
    # per-pixel test is exact (noise-free frames) the background reaching in through the slit is
    # removed;
    # unchanged pixels enclosed by the person (a part with the background's grey) stay.
    unchanged = _compare_scalar(
        _absolute(difference), float(pixel_threshold), cv2.CMP_LE
    )  # 0 / 255
    free = cv2.bitwise_or(unchanged, _compare_scalar(mask.view(np.uint8), 0, cv2.CMP_EQ))
    free = cv2.copyMakeBorder(free, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=255)
    _, labels = cv2.connectedComponents(free, connectivity=4)
    outside = labels[1:-1, 1:-1] == labels[0, 0]
    return mask & ~outside


# OpenCV takes a Python number for the second operand of compare and absdiff; its generated stubs
# admit only arrays (opencv-python#1008), so the two calls with a scalar are ignored here only.
def _compare_scalar(src: np.ndarray, value: float, cmpop: int) -> np.ndarray:
    """cv2.compare of an image with a number: 255 where it holds, else 0 (uint8)."""
    return cv2.compare(src, value, cmpop)  # type: ignore[call-overload]


def _absolute(src: np.ndarray) -> np.ndarray:
    """|src| per pixel, by cv2.absdiff against 0 (saturated, in src's type)."""
    return cv2.absdiff(src, 0.0)  # type: ignore[call-overload]


# -------------------------------------------------------------------- facade
@dataclass
class Segmentation:
    """A frame's segmentation: raw and cleaned masks, kept regions and their bounding rectangle."""

    raw: np.ndarray  # (H, W) bool: what the segmenter flagged
    mask: np.ndarray  # (H, W) bool: cleaned, only the kept regions
    regions: list[Region] = field(default_factory=list)
    box: tuple[int, int, int, int] | None = None  # x, y, w, h enclosing all kept regions
    warming_up: bool = False  # no segmentation yet (learning the background / no previous frame)

    @classmethod
    def empty(cls, shape: tuple[int, int], warming_up: bool) -> 'Segmentation':
        """Nothing found in an image of ``shape``."""
        nothing = np.zeros(shape, bool)
        return cls(nothing, nothing, [], None, warming_up)


@dataclass
class SegmenterSettings:
    """Parameters of :class:`Segmenter` (the contour node's parameters of the same names)."""

    segmenter: str = 'background'  # 'background' or 'change'
    threshold: float = 4.0  # T of eq. (1), grey levels (before the noise floor)
    background_frames: int = 10  # N frames learnt by the background segmenter
    delete_below: int = 3  # cleanup k1
    fill_above: int = 5  # cleanup k2
    max_iterations: int = 10  # cleanup repetitions (upper bound)
    fill_holes: bool = True
    min_area: int = 200  # smallest kept region, pixels
    keep: str = 'largest'  # 'largest', 'all' or 'tracked' (overlapping the prior)
    noise_factor: float = (
        NOISE_FACTOR  # T is raised to this many sigmas of the measured noise (0: fixed T)
    )
    refine: bool = True  # per-pixel boundary refinement (undoes the 5x5 fit's spread)
    pixel_factor: float = 2.5  # boundary pixels need |g_k - g_j| > max(pixel_factor sigma, 0.5)
    exact_noise: float = (
        0.5  # below this noise sigma (grey levels) the per-pixel test is exact: carve
    )
    # background channels, do not fill 1 px slits (0: never)
    compensate_gain: bool = True  # background: follow slow global lighting changes
    learn_margin: int = 6  # sequence: pixels around the person not learnt from, px
    track_margin: int = 15  # tracked: the previous frame's person grown by this much is the prior
    # background: segment only the box around the previous person (and the tracked region) grown
    # by this many pixels (0: every whole frame), every full_frame_every frames the whole frame
    window_margin: int = 0
    full_frame_every: int = 15


class Segmenter:
    """Raw mask by the named segmenter, then cleanup, boundary refinement and region selection."""

    def __init__(self, settings: SegmenterSettings | None = None, **overrides) -> None:
        """Take settings as a :class:`SegmenterSettings` and/or keyword overrides of its fields."""
        settings = replace(settings or SegmenterSettings(), **overrides)
        if settings.segmenter not in SEGMENTERS:
            raise ValueError(
                f'unknown segmenter {settings.segmenter!r}; known: {", ".join(SEGMENTERS)}'
            )
        if settings.keep not in KEEP_MODES:
            raise ValueError(f'keep must be one of {", ".join(KEEP_MODES)}, got {settings.keep!r}')
        self.settings = settings
        self.method: ChangeSegmenter | SequenceSegmenter | BackgroundSegmenter
        if settings.segmenter == 'change':
            self.method = ChangeSegmenter(settings.threshold, settings.noise_factor)
        elif settings.segmenter == 'sequence':
            self.method = SequenceSegmenter(
                settings.threshold, settings.background_frames, learn_margin=settings.learn_margin
            )
        else:
            self.method = BackgroundSegmenter(
                settings.threshold,
                settings.background_frames,
                settings.noise_factor,
                settings.compensate_gain,
            )
        self.last_change: ChangeResult | None = None
        self.roi: np.ndarray | None = None  # where the tracked body is expected (bool), if known
        self.previous: np.ndarray | None = None  # the previous frame's kept person mask
        self._image: np.ndarray | None = None
        self._stamp_ns: int | None = None  # the frame raw() was given, its time
        self._window: tuple[int, int, int, int] | None = None  # this frame's (window_margin)
        self._sigma: float | None = None  # the noise of the last whole frame
        self._since_whole = 0  # frames segmented in a window since the last whole one

    @property
    def colour(self) -> bool:
        """True when the segmenter compares colour frames (the others take grey)."""
        return self.settings.segmenter == 'sequence'

    def reset(self) -> None:
        """Forget the frame history (previous frame or learnt background) and tracked region."""
        self.method.reset()
        self.roi = self.previous = None
        self._window = self._sigma = None
        self._since_whole = 0

    def set_roi(self, roi: np.ndarray | None) -> None:
        """Where the tracked body is expected in the next frames (bool (H, W)); None: not known."""
        self.roi = None if roi is None else np.asarray(roi, bool)

    def raw(self, image: np.ndarray, stamp_ns: int | None = None) -> ChangeResult | None:
        """Return the segmenter's eq. (1) result (raw mask, difference, noise).

        None while warming up.  ``stamp_ns``, the frame's time, paces the sequence segmenter's
        learning (:meth:`SequenceSegmenter.segment`).
        """
        self._image, self._stamp_ns = image, stamp_ns
        self._window = self._choose_window(np.shape(image)[:2])
        if self._window is None:
            return self._whole_frame()
        assert isinstance(self.method, BackgroundSegmenter)
        self.last_change = self.method.segment(image, self._window, self._sigma)
        self._since_whole += 1
        return self.last_change

    def _whole_frame(self) -> ChangeResult | None:
        """Eq. (1) over the whole frame (its noise kept for the windows that follow)."""
        self._window = None
        assert self._image is not None  # raw() keeps the frame before any segmentation
        if isinstance(self.method, SequenceSegmenter):
            self.last_change = self.method.segment(self._image, self._stamp_ns)
        else:
            self.last_change = self.method.segment(self._image)
        if self.last_change is not None:
            self._sigma, self._since_whole = self.last_change.sigma, 0
        return self.last_change

    def _choose_window(self, shape: tuple[int, int]) -> tuple[int, int, int, int] | None:
        """Return the box (x, y, w, h) this frame is segmented in, None for the whole frame.

        window_margin: the previous frame's person and the tracked region, grown; the whole
        frame every full_frame_every frames (a person who enters is found then), while the
        background is learnt, and when the box would be most of the frame anyway.
        """
        s = self.settings
        if (
            s.window_margin <= 0
            or not isinstance(self.method, BackgroundSegmenter)
            or self.method.warming_up
            or self._sigma is None
            or self._since_whole + 1 >= s.full_frame_every
            or self.previous is None
            or self.previous.shape != shape
        ):
            return None
        around = self.previous
        if self.roi is not None and self.roi.shape == shape:
            around = around | self.roi
        if not around.any():
            return None
        box = _grown_box(around, s.window_margin)
        return None if box[2] * box[3] > WINDOW_MOST * shape[0] * shape[1] else box

    def _prior(self, shape: tuple[int, int]) -> np.ndarray | None:
        """Return the tracked region.

        The body's projection, else the previous frame's person grown.
        """
        if self.roi is not None and self.roi.shape == shape:
            return self.roi
        if self.previous is None or self.previous.shape != shape or not self.previous.any():
            return None
        size = 2 * self.settings.track_margin + 1
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
        return cv2.dilate(self.previous.view(np.uint8), kernel).view(bool)

    def refine(self, change: ChangeResult) -> Segmentation:
        """Cleanup, boundary refinement, cleanup again, region selection of a raw eq. (1) mask.

        A window whose person reaches its inner edge is given up: the whole frame is segmented.
        """
        shape = np.shape(self._image)[:2] if self._image is not None else change.mask.shape
        refined = self._refined(change, self._window, shape)
        if refined is None:
            whole = self._whole_frame()
            assert whole is not None  # the background that gave the window is still there
            refined = self._refined(whole, None, shape)
            assert refined is not None
        raw, mask, regions = refined
        self.previous = mask
        learn = getattr(self.method, 'learn', None)
        if learn is not None and self._image is not None:
            roi = self.roi if self.roi is not None and self.roi.shape == mask.shape else None
            learn(self._image, mask, roi)
        return Segmentation(raw, mask, regions, union_box(regions), False)

    def _refined(
        self,
        change: ChangeResult,
        window: tuple[int, int, int, int] | None,
        shape: tuple[int, int],
    ) -> tuple[np.ndarray, np.ndarray, list[Region]] | None:
        """Return the raw mask, the kept mask and its regions (whole-frame coordinates).

        None when the window's person touches one of its edges inside the frame.
        """
        s = self.settings
        raw = change.mask
        cleaned = cleanup(raw, s.delete_below, s.fill_above, s.max_iterations, s.fill_holes)
        if window is not None and _reaches_inner_edge(cleaned, window, shape):
            return None
        if s.refine and cleaned.any():
            pixel_threshold = max(s.pixel_factor * change.sigma, PIXEL_FLOOR)
            exact = change.sigma < s.exact_noise
            box = _slices(_grown_box(cleaned, 3))
            sharp = refine_boundary(
                raw[box], cleaned[box], change.difference[box], pixel_threshold
            )
            fill_above = s.fill_above
            if exact:  # no noise to clean: keep slits between parts, which cleanup would close
                sharp = carve_background_channels(sharp, change.difference[box], pixel_threshold)
                fill_above = max(fill_above, EXACT_FILL_ABOVE)
            cleaned = np.zeros_like(cleaned)
            cleaned[box] = cleanup(
                sharp, s.delete_below, fill_above, s.max_iterations, s.fill_holes
            )
        prior = self._prior(shape) if s.keep == 'tracked' else None
        if window is None:
            mask, regions = select_regions(cleaned, s.min_area, s.keep, prior)
            return raw.copy(), mask, regions
        view = _slices(window)
        mask, regions = select_regions(
            cleaned, s.min_area, s.keep, None if prior is None else prior[view]
        )
        x0, y0 = window[:2]
        whole_raw, whole_mask = np.zeros(shape, bool), np.zeros(shape, bool)
        whole_raw[view], whole_mask[view] = raw, mask
        moved = [
            Region(
                r.area, (r.box[0] + x0, r.box[1] + y0, r.box[2], r.box[3]), r.outline + (x0, y0)
            )
            for r in regions
        ]
        return whole_raw, whole_mask, moved

    def process(self, image: np.ndarray, stamp_ns: int | None = None) -> Segmentation:
        """Segment one frame: grey uint8 (H, W), or (H, W, C) for the sequence segmenter."""
        change = self.raw(image, stamp_ns)
        if change is None:
            return Segmentation.empty(np.shape(image)[:2], True)
        return self.refine(change)


def _slices(window: tuple[int, int, int, int]) -> tuple[slice, slice]:
    """Return the array slices (rows, columns) of a box (x, y, w, h)."""
    x, y, w, h = window
    return np.s_[y : y + h, x : x + w]


def _reaches_inner_edge(
    mask: np.ndarray, window: tuple[int, int, int, int], shape: tuple[int, int]
) -> bool:
    """Whether ``mask`` (the window's) has a flag on an edge of the window inside the frame."""
    x, y, w, h = window
    height, width = shape
    return bool(
        (y > 0 and mask[0].any())
        or (y + h < height and mask[-1].any())
        or (x > 0 and mask[:, 0].any())
        or (x + w < width and mask[:, -1].any())
    )


def _grown_box(mask: np.ndarray, margin: int) -> tuple[int, int, int, int]:
    """Bounding box (x, y, w, h) of a mask's flags grown by ``margin`` and clipped to the image."""
    x, y, w, h = cv2.boundingRect(mask.view(np.uint8))
    height, width = mask.shape
    x0, y0 = max(x - margin, 0), max(y - margin, 0)
    return x0, y0, min(x + w + margin, width) - x0, min(y + h + margin, height) - y0
