"""Rohr's change detection (§4.1, eq. 1): compare 5x5 quadratic fits of two frames.

For each pixel the grey values of its 5x5 window are approximated by a
bivariate polynomial of second order, g = X beta (X: the 25x6 design matrix of
1, x, y, x^2, xy, y^2 over the offsets -2..2); the pixel shows a systematic
change between frames k and j when

    (1/sqrt(n)) || X X* (g_k - g_j) ||_2 > T,   X* = (X^T X)^-1 X^T,  n = 25.   (1)

X X* is the orthogonal projection onto the span of the quadratic basis.  With
the 1-D polynomials p0, p1, p2 orthonormal on {-2..2}, the six products
p_a(x) p_b(y), a + b <= 2, are an orthonormal basis of that same span, so

    || X X* d ||^2 = sum_{a+b<=2} <d, p_a (x) p_b>^2,

i.e. six separable 5x5 correlations of the frame difference d (computed from
three row passes and six column passes).  Borders: windows reaching outside
the image are completed by reflect-101 padding (``cv2.BORDER_REFLECT_101``,
numpy's ``mode='reflect'``) in both the fast and the reference implementation,
so every pixel, the border ones included, gets a statistic.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

WINDOW = 5  # Rohr: 5x5 window
N_WINDOW = WINDOW * WINDOW  # n in eq. (1)
_OFFSETS = np.arange(-2, 3, dtype=np.float64)
# 1-D polynomials orthonormal on {-2, ..., 2}: 1, x, x^2 - 2
P0 = np.ones(5) / np.sqrt(5.0)
P1 = _OFFSETS / np.sqrt(10.0)
P2 = (_OFFSETS**2 - 2.0) / np.sqrt(14.0)
_P = (P0.astype(np.float32), P1.astype(np.float32), P2.astype(np.float32))
# the six 2-D basis functions p_a(x) p_b(y), a + b <= 2, as (a: along x, b: along y)
BASIS = ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2))


def design_matrix() -> np.ndarray:
    """Rohr's X: rows (1, x, y, x^2, xy, y^2) over the 5x5 offsets, row-major in (y, x) (25x6)."""
    y, x = (grid.ravel() for grid in np.meshgrid(_OFFSETS, _OFFSETS, indexing='ij'))
    return np.stack([np.ones(25), x, y, x * x, x * y, y * y], axis=1)


class Workspace:
    """Reusable float32 buffers for one image size.

    Fresh 1 MB arrays per frame cost more than the filtering.
    """

    def __init__(self) -> None:
        """No buffers until the first image size is known."""
        self.shape: tuple[int, int] | None = None

    def buffers(self, shape: tuple[int, int]) -> 'Workspace':
        """(Re)allocate the buffers when the image size changes; returns self."""
        if shape != self.shape:
            self.shape = shape
            self.difference = np.empty(shape, np.float32)
            self.rows = [np.empty(shape, np.float32) for _ in range(3)]
            self.coefficient = np.empty(shape, np.float32)
            self.energy = np.empty(shape, np.float32)
            self.mask = np.empty(shape, bool)
        return self


_ROW_KERNELS = tuple(p.reshape(1, WINDOW) for p in _P)  # correlate along x with p_a
_COLUMN_KERNELS = tuple(p.reshape(WINDOW, 1) for p in _P)  # correlate along y with p_b
_BORDER = cv2.BORDER_REFLECT_101


def _difference(frame_k: np.ndarray, frame_j: np.ndarray, out: np.ndarray) -> np.ndarray:
    """g_k - g_j as float32 into ``out`` (any numeric dtype in, same 2-D shape required)."""
    a, b = np.asarray(frame_k), np.asarray(frame_j)
    if a.shape != b.shape or a.ndim != 2:
        raise ValueError(
            f'change detection needs two grey frames of one shape, got {a.shape} and {b.shape}'
        )
    if a.dtype != b.dtype or a.dtype not in (np.uint8, np.uint16, np.int16, np.float32):
        a, b = a.astype(np.float32), b.astype(np.float32)
    return cv2.subtract(a, b, dst=out, dtype=cv2.CV_32F)


def _energy(difference: np.ndarray, ws: Workspace) -> np.ndarray:
    """||X X* d||^2 into ws.energy: three row passes, six column passes, sum of squares (eq. 1)."""
    for a in range(3):
        cv2.filter2D(difference, cv2.CV_32F, _ROW_KERNELS[a], dst=ws.rows[a], borderType=_BORDER)
    ws.energy.fill(0.0)
    for a, b in BASIS:  # coefficient of p_a(x) p_b(y)
        cv2.filter2D(
            ws.rows[a], cv2.CV_32F, _COLUMN_KERNELS[b], dst=ws.coefficient, borderType=_BORDER
        )
        cv2.accumulateSquare(ws.coefficient, ws.energy)
    return ws.energy


def projected_energy(difference: np.ndarray, workspace: Workspace | None = None) -> np.ndarray:
    """||X X* d||^2 per pixel of a difference image.

    Sum of six separable correlations squared (eq. 1).
    """
    d = np.ascontiguousarray(difference, np.float32)
    ws = (workspace or Workspace()).buffers(d.shape)
    return _energy(d, ws)


def change_statistic(
    frame_k: np.ndarray, frame_j: np.ndarray, workspace: Workspace | None = None
) -> np.ndarray:
    """Left side of eq. (1), (1/sqrt(n)) ||X X* (g_k - g_j)||, per pixel.

    New float32 image, grey levels.
    """
    ws = (workspace or Workspace()).buffers(np.shape(frame_k)[:2])
    energy = _energy(_difference(frame_k, frame_j, ws.difference), ws)
    return np.sqrt(energy) * np.float32(1.0 / np.sqrt(N_WINDOW))


def change_mask(
    frame_k: np.ndarray, frame_j: np.ndarray, threshold: float, workspace: Workspace | None = None
) -> np.ndarray:
    """Pixels with systematic change between two frames.

    Eq. (1) > T (bool; a view of the workspace if given).
    """
    ws = (workspace or Workspace()).buffers(np.shape(frame_k)[:2])
    energy = _energy(_difference(frame_k, frame_j, ws.difference), ws)
    return np.greater(
        energy, np.float32(N_WINDOW * float(threshold) ** 2), out=ws.mask
    )  # eq. (1)^2: > n T^2


# chi-square quantiles with 6 degrees of freedom: under pure noise of sigma_d per pixel,
# n * statistic^2 / sigma_d^2 = ||X X* d||^2 / sigma_d^2 is chi-square(6) (projection onto 6
# dimensions)
_CHI2_6_Q25 = 3.4546  # 25th percentile, for the noise estimate
NOISE_FACTOR = (
    1.25  # sqrt(chi2_6 quantile 1 - 1e-6 = 38.26) / 5: one false pixel per 10^6 under noise
)


def noise_sigma(energy: np.ndarray, stride: int = 4) -> float:
    """Sigma of the per-pixel difference noise from the lower quartile of ||X X* d||^2.

    Most pixels unchanged.
    """
    sample = np.ascontiguousarray(energy[::stride, ::stride]).ravel()
    if sample.size == 0:
        return 0.0
    q25 = float(np.partition(sample, sample.size // 4)[sample.size // 4])
    return float(np.sqrt(q25 / _CHI2_6_Q25)) if q25 > 0 else 0.0  # energy ~ sigma^2 chi2(6)


@dataclass
class ChangeResult:
    """Eq. (1) between two frames.

    The mask, the difference g_k - g_j, the noise and the threshold used.
    """

    mask: (
        np.ndarray
    )  # (H, W) bool, eq. (1) > threshold (workspace buffer: valid until the next call)
    difference: np.ndarray  # (H, W) float32 g_k - g_j (workspace buffer)
    sigma: float  # estimated per-pixel noise of the difference, grey levels
    threshold: float  # T actually applied: max(T, noise_factor * sigma)


def detect_changes(
    frame_k: np.ndarray,
    frame_j: np.ndarray,
    threshold: float,
    noise_factor: float = NOISE_FACTOR,
    workspace: Workspace | None = None,
    sigma: float | None = None,
) -> ChangeResult:
    """Eq. (1) with T raised to ``noise_factor`` x the measured difference noise.

    0 = Rohr's fixed T.  ``sigma``: the noise as measured before, for a window of a frame
    that the person fills too much for its lower quartile to be noise.
    """
    ws = (workspace or Workspace()).buffers(np.shape(frame_k)[:2])
    difference = _difference(frame_k, frame_j, ws.difference)
    energy = _energy(difference, ws)
    if sigma is None:
        sigma = noise_sigma(energy) if noise_factor > 0 else 0.0
    applied = max(float(threshold), noise_factor * sigma)
    mask = np.greater(energy, np.float32(N_WINDOW * applied**2), out=ws.mask)  # eq. (1)^2: > n T^2
    return ChangeResult(mask, difference, sigma, applied)


def change_statistic_reference(frame_k: np.ndarray, frame_j: np.ndarray) -> np.ndarray:
    """Brute-force eq. (1).

    An explicit least-squares fit per 5x5 window (float64; for tests on small images).
    """
    d = np.asarray(frame_k, np.float64) - np.asarray(frame_j, np.float64)
    padded = np.pad(d, 2, mode='reflect')  # = cv2.BORDER_REFLECT_101
    windows = np.lib.stride_tricks.sliding_window_view(padded, (WINDOW, WINDOW))  # (H, W, 5, 5)
    g = windows.reshape(-1, N_WINDOW).T  # (25, H*W), row-major (y, x) like X
    X = design_matrix()
    beta, *_ = np.linalg.lstsq(X, g, rcond=None)  # beta = X* (g_k - g_j)
    fitted = X @ beta  # X X* (g_k - g_j)
    return (np.linalg.norm(fitted, axis=0) / np.sqrt(N_WINDOW)).reshape(d.shape)  # eq. (1)


class ChangeDetector:
    """Live change detection: each frame against the previous one (eq. 1 with j = k - 1)."""

    def __init__(self, threshold: float = 12.0, noise_factor: float = 0.0) -> None:
        """``threshold``.

        T of eq. (1), grey levels; ``noise_factor`` > 0 raises T to that many noise sigmas.
        """
        self.threshold = float(threshold)
        self.noise_factor = float(noise_factor)
        self.previous: np.ndarray | None = None
        self.workspace = Workspace()

    def reset(self) -> None:
        """Forget the previous frame (after a time jump).

        So the next frame only primes the detector.
        """
        self.previous = None

    def detect(self, frame: np.ndarray) -> ChangeResult | None:
        """Eq. (1) of ``frame`` against the previous frame (buffers valid until the next call).

        None at first.
        """
        frame = np.asarray(frame)
        previous = self.previous
        if previous is None or previous.shape != frame.shape or previous.dtype != frame.dtype:
            self.previous = frame.copy()
            return None
        result = detect_changes(frame, previous, self.threshold, self.noise_factor, self.workspace)
        np.copyto(previous, frame)  # keep the buffer: no per-frame allocation
        return result

    def update(self, frame: np.ndarray) -> np.ndarray | None:
        """Return the changed pixels of ``frame`` against the previous frame, None at first.

        A bool image, valid until the next call.
        """
        result = self.detect(frame)
        return None if result is None else result.mask
