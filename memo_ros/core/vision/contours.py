"""Occluding contours (Kakadiaris & Metaxas §4.1, step 1) and the per-frame contour pipeline.

Each kept region's outer outline (``cv2.findContours``, ``RETR_EXTERNAL``,
``CHAIN_APPROX_NONE``) is resampled at a fixed arc-length step and fitted by a
closed smooth curve, "a smooth differentiable model of the curve": its Fourier
series with a Gaussian low-pass along the arc (``smoothing`` = the Gaussian's
standard deviation in pixels of arc length; 0 = none), whose analytic
derivative gives the unit tangent at every sample.  (A periodic smoothing
spline, ``scipy.interpolate.splprep(per=1)``, gives equivalent curves but costs
1-4 ms per 640x480 frame in its knot search against ~0.1 ms here.)

Orientation: every contour runs counter-clockwise as the image is displayed
(x right, y down), i.e. with a negative shoelace area in pixel coordinates; the
region lies on the left of the direction of travel on screen, and the outward
unit normal is ``(-ty, tx)``.  Coordinates follow OpenCV: pixel (0, 0) is the
centre of the top-left pixel.

:class:`ContourPipeline` runs a grey frame through segmentation, cleanup,
contours and edge lines (Rohr §4.3) and times each stage.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
import time

import numpy as np

from memo_ros.core.vision.background import grey_of
from memo_ros.core.vision.edges import EDGE_DTYPE, edge_lines_in_boxes
from memo_ros.core.vision.segmentation import (
    BackgroundSegmenter,
    Region,
    Segmentation,
    Segmenter,
    SegmenterSettings,
    select_regions,
)

# one row per contour sample; the same layout as the /<cam>/contours PointCloud2 fields
CONTOUR_DTYPE = np.dtype(
    [('x', '<f4'), ('y', '<f4'), ('tx', '<f4'), ('ty', '<f4'), ('contour', '<u4')]
)
MIN_SMOOTH_SAMPLES = 8  # fewer samples: no smoothing, the polygon with finite-difference tangents


# ------------------------------------------------------------------ contours
def resample_closed(points: np.ndarray, step: float) -> np.ndarray:
    """Points spaced ``step`` pixels along a closed polyline (N, 2).

    At least 3 when it has any length.
    """
    p = np.asarray(points, np.float64).reshape(-1, 2)
    closed = np.vstack([p, p[:1]])
    seg = np.hypot(*np.diff(closed, axis=0).T)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    length = arc[-1]
    if length <= 0.0:
        return p[:1].copy()
    count = max(int(round(length / step)), 3)
    s = np.arange(count) * (length / count)
    return np.stack([np.interp(s, arc, closed[:, 0]), np.interp(s, arc, closed[:, 1])], axis=1)


def _orient_ccw_on_screen(p: np.ndarray) -> np.ndarray:
    """Return the same closed polyline.

    Reversed if needed so that its shoelace area (y down) is negative.
    """
    x, y = p[:, 0], p[:, 1]
    area2 = np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y)
    return p[::-1].copy() if area2 > 0 else p


def _polygon_tangents(p: np.ndarray) -> np.ndarray:
    """Return unit tangents of a closed polyline by central differences (zeros where undefined)."""
    d = np.roll(p, -1, axis=0) - np.roll(p, 1, axis=0)
    norm = np.hypot(d[:, 0], d[:, 1])
    return np.where(norm[:, None] > 0, d / np.maximum(norm, 1e-12)[:, None], 0.0)


def smooth_closed_contour(
    outline: np.ndarray, step: float = 2.0, smoothing: float = 2.0, offset: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Return samples (M, 2) of a closed outline every ``step`` px, low-passed along its arc.

    And unit tangents (M, 2).
    """
    # ``offset`` moves the samples along the outward normal (-ty, tx): 0.5 px takes the centres of
    # a
    # region's boundary pixels to the pixel edges, where the silhouette's boundary lies.
    # The closed curve is the Fourier series of the uniformly resampled outline z(s) = x(s) + i
    # y(s)
    # with every harmonic damped by a Gaussian of standard deviation ``smoothing`` px of arc
    # length:
    # a smooth, differentiable closed model of the contour; its derivative dz/ds (harmonics times
    # 2 pi i f) is evaluated analytically at the same samples and normalised to the tangent.
    samples = resample_closed(outline, step)
    if len(samples) < 3:
        return samples, np.zeros_like(samples)
    samples = _orient_ccw_on_screen(samples)
    m = len(samples)
    if m < MIN_SMOOTH_SAMPLES:
        return samples, _polygon_tangents(samples)
    spacing = perimeter(samples) / m  # arc length per sample (about ``step``)
    frequency = np.fft.fftfreq(m, d=spacing)  # cycles per pixel of arc length
    spectrum = np.fft.fft(samples[:, 0] + 1j * samples[:, 1])
    spectrum *= np.exp(-0.5 * (2.0 * np.pi * frequency * float(smoothing)) ** 2)
    if m % 2 == 0:
        spectrum[m // 2] = 0.0  # Nyquist term: no well-defined derivative
    z = np.fft.ifft(spectrum)
    dz = np.fft.ifft(spectrum * (2j * np.pi * frequency))
    norm = np.abs(dz)
    if np.any(norm <= 1e-9):
        return samples, _polygon_tangents(samples)
    tangent = np.stack([dz.real / norm, dz.imag / norm], axis=1)
    xy = np.stack([z.real - offset * tangent[:, 1], z.imag + offset * tangent[:, 0]], axis=1)
    return _respace(xy, tangent, step)


def _respace(xy: np.ndarray, tangent: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Return samples of a smooth closed curve moved to spacing ``step`` along its own arc.

    The pixel staircase was longer.
    """
    closed_xy = np.vstack([xy, xy[:1]])
    closed_t = np.vstack([tangent, tangent[:1]])
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(closed_xy, axis=0).T))])
    count = max(int(round(arc[-1] / step)), 3)
    s = np.arange(count) * (arc[-1] / count)
    out_xy = np.stack(
        [np.interp(s, arc, closed_xy[:, 0]), np.interp(s, arc, closed_xy[:, 1])], axis=1
    )
    t = np.stack([np.interp(s, arc, closed_t[:, 0]), np.interp(s, arc, closed_t[:, 1])], axis=1)
    norm = np.hypot(t[:, 0], t[:, 1])
    if np.any(norm <= 1e-6):  # a cusp between two samples: keep the original samples
        return xy, tangent
    return out_xy, t / norm[:, None]


def perimeter(p: np.ndarray) -> float:
    """Length of a closed polyline."""
    d = np.diff(np.vstack([p, p[:1]]), axis=0)
    return float(np.hypot(d[:, 0], d[:, 1]).sum())


def silhouette_outlines(mask: np.ndarray, min_area: int = 200) -> list[np.ndarray]:
    """Outer outlines (float pixels) of every region of a binary mask.

    Kept as contour_node keeps them.
    """
    _, regions = select_regions(mask, min_area, keep='all')
    return [r.outline.astype(float) for r in regions]


def occluding_contours(
    outlines: list[np.ndarray], step: float = 2.0, smoothing: float = 2.0, offset: float = 0.5
) -> np.ndarray:
    """Smoothed samples of each outline with unit tangents.

    a CONTOUR_DTYPE table, contour id = outline index.
    """
    if step <= 0:
        raise ValueError(f'contour step must be positive, got {step}')
    if smoothing < 0:
        raise ValueError(f'smoothing must not be negative, got {smoothing}')
    parts = []
    for index, outline in enumerate(outlines):
        if outline is None or len(outline) == 0:
            continue
        xy, t = smooth_closed_contour(outline, step, smoothing, offset)
        table = np.empty(len(xy), CONTOUR_DTYPE)
        table['x'], table['y'] = xy[:, 0], xy[:, 1]
        table['tx'], table['ty'] = t[:, 0], t[:, 1]
        table['contour'] = index
        parts.append(table)
    return np.concatenate(parts) if parts else np.zeros(0, CONTOUR_DTYPE)


# ------------------------------------------------------------------ pipeline
@dataclass
class PipelineSettings(SegmenterSettings):
    """Everything the contour pipeline needs: segmentation (inherited), contours and edge lines."""

    contour_step: float = 2.0  # arc length between contour samples, pixels
    smoothing: float = 2.0  # Gaussian low-pass along the contour: sigma, px of arc length
    contour_offset: float = 0.5  # outward shift from boundary-pixel centres to the pixel edges, px
    edges: bool = True  # compute Rohr's edge lines in the enclosing rectangle
    edge_low: float = 30.0  # Canny hysteresis thresholds (L2 magnitude of the 3x3 Sobel)
    edge_high: float = 80.0
    min_edge_length: float = 6.0  # shortest edge line kept, pixels
    edge_tolerance: float = 1.5  # largest distance of a chain point from its line, pixels
    edge_margin: int = 3  # each region's rectangle is grown by this much for edge detection


@dataclass
class PipelineResult:
    """One frame through the pipeline."""

    mask: np.ndarray  # (H, W) bool: the kept person regions
    box: tuple[int, int, int, int] | None  # x, y, w, h enclosing them, None when nobody is seen
    contours: np.ndarray  # CONTOUR_DTYPE table
    edges: np.ndarray  # EDGE_DTYPE table
    timings: dict[str, float] = field(default_factory=dict)  # stage -> seconds
    warming_up: bool = False
    segmentation: Segmentation | None = None
    regions: list[Region] = field(default_factory=list)


class ContourPipeline:
    """Grey frame -> person mask, enclosing rectangle, occluding contours, edge lines.

    Per-stage timings.
    """

    STAGES = ('segment', 'cleanup', 'contours', 'edges')

    def __init__(self, settings: PipelineSettings | None = None, **overrides) -> None:
        """Take settings as a :class:`PipelineSettings` and/or keyword overrides of its fields."""
        settings = replace(settings or PipelineSettings(), **overrides)
        if settings.contour_step <= 0:
            raise ValueError(f'contour_step must be positive, got {settings.contour_step}')
        if settings.smoothing < 0:
            raise ValueError(f'smoothing must not be negative, got {settings.smoothing}')
        self.settings = settings
        base = {f.name: getattr(settings, f.name) for f in fields(SegmenterSettings)}
        self.segmenter = Segmenter(SegmenterSettings(**base))

    def reset(self) -> None:
        """Forget the frame history (time jump, bag loop): previous frame or learnt background."""
        self.segmenter.reset()

    def set_background(self, background: np.ndarray) -> None:
        """Background segmenter: use this grey picture of the empty scene, not a learnt one."""
        if not isinstance(self.segmenter.method, BackgroundSegmenter):
            raise ValueError('set_background needs the background segmenter')
        self.segmenter.method.set_background(background)

    @property
    def background(self) -> np.ndarray | None:
        """The background segmenter's learnt (or given) background.

        None while learning or for change detection.
        """
        method = self.segmenter.method
        return method.background if isinstance(method, BackgroundSegmenter) else None

    @property
    def moved_while_learning(self) -> int:
        """Pixels that moved in the frames the background was learnt from (0 when given)."""
        method = self.segmenter.method
        return method.moved_pixels if isinstance(method, BackgroundSegmenter) else 0

    def set_roi(self, roi: np.ndarray | None) -> None:
        """Where the tracked body is expected (bool (H, W)).

        For keep='tracked' and the sequence segmenter.
        """
        self.segmenter.set_roi(roi)

    def process(
        self, image: np.ndarray, edges: bool | None = None, stamp_ns: int | None = None
    ) -> PipelineResult:
        """Run one frame through every stage.

        Grey uint8 (H, W), or (H, W, C) for the sequence segmenter.

        ``edges`` overrides the settings' choice of computing the edge lines (only Rohr's walker
        uses them: a node computes them when someone listens).  ``stamp_ns``: the frame's time
        (the sequence segmenter learns from frames a time apart, not a count).
        """
        s = self.settings
        want_edges = s.edges if edges is None else edges
        image = np.asarray(image)
        if image.ndim != 2 and not (self.segmenter.colour and image.ndim == 3):
            raise ValueError(f'the pipeline takes one grey (H, W) frame, got shape {image.shape}')
        grey = image if image.ndim == 2 else grey_of(image)
        clock = time.perf_counter
        t0 = clock()
        change = self.segmenter.raw(image if self.segmenter.colour else grey, stamp_ns)
        t1 = clock()
        timings = {'segment': t1 - t0}
        if change is None:
            segmentation = Segmentation.empty(grey.shape, True)
            timings.update(cleanup=0.0, contours=0.0, edges=0.0)
            return PipelineResult(
                segmentation.mask,
                None,
                np.zeros(0, CONTOUR_DTYPE),
                np.zeros(0, EDGE_DTYPE),
                timings,
                True,
                segmentation,
                [],
            )
        segmentation = self.segmenter.refine(change)
        t2 = clock()
        contours = occluding_contours(
            [r.outline for r in segmentation.regions],
            s.contour_step,
            s.smoothing,
            s.contour_offset,
        )
        t3 = clock()
        lines = (
            self._edge_lines(grey, segmentation.box, segmentation.regions)
            if want_edges
            else np.zeros(0, EDGE_DTYPE)
        )
        t4 = clock()
        timings.update(cleanup=t2 - t1, contours=t3 - t2, edges=t4 - t3)
        return PipelineResult(
            segmentation.mask,
            segmentation.box,
            contours,
            lines,
            timings,
            False,
            segmentation,
            segmentation.regions,
        )

    def edge_lines(self, image: np.ndarray, result: PipelineResult) -> np.ndarray:
        """Rohr's edge lines of a frame :meth:`process` took without them (EDGE_DTYPE).

        The same lines as ``process(image, edges=True)`` gives: a node whose edges gained a
        subscriber while the frame was processed still publishes them with it.
        """
        image = np.asarray(image)
        grey = image if image.ndim == 2 else grey_of(image)
        return self._edge_lines(grey, result.box, result.regions)

    def _edge_lines(self, grey: np.ndarray, box, regions: list[Region]) -> np.ndarray:
        """Edge lines in each kept region's rectangle; none when nobody is seen."""
        if box is None:
            return np.zeros(0, EDGE_DTYPE)
        s = self.settings
        return edge_lines_in_boxes(
            grey,
            [r.box for r in regions],
            s.edge_low,
            s.edge_high,
            s.min_edge_length,
            s.edge_tolerance,
            s.edge_margin,
        )


__all__ = [
    'CONTOUR_DTYPE',
    'EDGE_DTYPE',
    'ContourPipeline',
    'PipelineResult',
    'PipelineSettings',
    'occluding_contours',
    'perimeter',
    'resample_closed',
    'silhouette_outlines',
    'smooth_closed_contour',
]
