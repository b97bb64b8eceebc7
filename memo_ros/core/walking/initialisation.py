"""Rohr §5.1/§6.

Starting values from the single-image estimates of about half a cycle (images 2-14).

The pose estimates lie approximately on two lines half a cycle apart (the actual movement and the
one with the legs swapped).  The lines are found by a robust fit of ``pose = phi + v k (mod 1/2)``;
if one line holds more than half as many estimates as the other, the line with the higher mean
similarity wins, else the line with more estimates.  Starting values come from linear regression:
pose and pose' over all estimates mapped onto the chosen line, X and X' over the positions, Y and Z
as medians (robust to a rectangle that lost a limb).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class SingleEstimate:
    """The best grid point of one initialization image."""

    image: float  # image number (from the stamp)
    X: float
    Y: float
    Z: float
    pose: float
    similarity: float


@dataclass
class LineChoice:
    """The two-lines decision: the chosen line's pose at image 0, its slope, how it was chosen."""

    phase0: float  # pose at image number 0 on the chosen line (unwrapped)
    slope: float  # pose per image
    on_chosen: np.ndarray  # (n,) bool: estimate lies on the chosen line
    on_other: np.ndarray  # (n,) bool: estimate lies on the displaced line
    counts: tuple[int, int]  # (chosen, displaced)
    mean_similarity: tuple[float, float]
    rule: str  # 'count' or 'similarity'


def wrap(value, period: float = 1.0):
    """``value`` wrapped into [-period/2, period/2)."""
    return np.mod(np.asarray(value, float) + period / 2.0, period) - period / 2.0


def two_lines(
    images: np.ndarray,
    poses: np.ndarray,
    similarities: np.ndarray,
    slopes: tuple[float, float] = (0.01, 0.08),
    tolerance: float = 0.05,
) -> LineChoice:
    """Group pose estimates onto two lines half a cycle apart; choose one by the paper's rule."""
    k = np.asarray(images, float)
    pose = np.mod(np.asarray(poses, float), 1.0)
    sim = np.asarray(similarities, float)
    v = np.arange(slopes[0], slopes[1] + 1e-9, 0.0005)[:, None, None]
    phi = np.arange(0.0, 0.5, 0.0025)[None, :, None]
    residual = np.abs(wrap(pose[None, None] - phi - v * k[None, None], 0.5))  # (V, F, n)
    inlier = residual < tolerance
    score = inlier.sum(-1) - np.where(inlier, residual, 0.0).sum(-1) / (tolerance * len(k) + 1e-9)
    iv, iphi = np.unravel_index(np.argmax(score), score.shape)
    slope, base = float(v[iv, 0, 0]), float(phi[0, iphi, 0])
    on_line = inlier[iv, iphi]
    offset = wrap(pose - base - slope * k, 1.0)  # near 0: line A, near +-0.5: line B
    line_a = on_line & (np.abs(offset) < 0.25)
    line_b = on_line & ~line_a
    n_a, n_b = int(line_a.sum()), int(line_b.sum())
    s_a = float(sim[line_a].mean()) if n_a else 0.0
    s_b = float(sim[line_b].mean()) if n_b else 0.0
    if min(n_a, n_b) > max(n_a, n_b) / 2.0:
        rule, pick_a = 'similarity', s_a >= s_b
    else:
        rule, pick_a = 'count', n_a >= n_b
    chosen, other = (line_a, line_b) if pick_a else (line_b, line_a)
    phase0 = base if pick_a else base + 0.5
    # linear regression over every estimate on either line, mapped onto the chosen one
    mapped = phase0 + slope * k + wrap(pose - phase0 - slope * k, 0.5)
    fit, intercept = (
        np.polyfit(k[on_line], mapped[on_line], 1) if on_line.sum() >= 2 else (slope, phase0)
    )
    counts = (int(chosen.sum()), int(other.sum()))
    means = (s_a, s_b) if pick_a else (s_b, s_a)
    return LineChoice(float(intercept), float(fit), chosen, other, counts, means, rule)


def starting_state(
    estimates: list[SingleEstimate], at_image: float, choice: LineChoice
) -> np.ndarray:
    """Return p_0 = (X, X', Y, 0, Z, 0, pose, pose') at image ``at_image``.

    From the regressions and medians of the estimates.
    """
    k = np.array([e.image for e in estimates])
    X = np.array([e.X for e in estimates])
    slope_x, intercept_x = np.polyfit(k, X, 1)
    # a gross outlier (a match on the wrong body half) must not tilt the line: refit without > 3
    # MAD
    residual = X - (intercept_x + slope_x * k)
    mad = np.median(np.abs(residual - np.median(residual))) + 1e-3
    keep = np.abs(residual) <= 3.0 * 1.4826 * mad
    if keep.sum() >= 2:
        slope_x, intercept_x = np.polyfit(k[keep], X[keep], 1)
    Y = float(np.median([e.Y for e in estimates]))
    Z = float(
        np.median([e.Z for e in estimates])
    )  # a rectangle that lost the head must not pull it
    pose = choice.phase0 + choice.slope * at_image
    return np.array(
        [intercept_x + slope_x * at_image, slope_x, Y, 0.0, Z, 0.0, pose, choice.slope]
    )
