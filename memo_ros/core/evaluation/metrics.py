"""Accuracy of estimated body poses against ground truth.

Joint-centre error (MPJPE, mm) over the pelvis and the 13 joints, per-part
translation error as a percentage of body height and per-part axis-direction
error in degrees (the figures Kakadiaris & Metaxas §5 report: 1 % translation,
2 % orientation), and the gait-phase error modulo the cycle for walking.

And what a silhouette tracker can get wrong as a whole: the heading error per
frame (where the torso faces about the vertical) and side swaps, frames where
the estimate's left and right arms or legs fit the truth better exchanged.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
import warnings

import numpy as np

from memo_ros.core.geometry.body import PART_NAMES

# each pair of limbs' parts whose origins (elbow, wrist; knee, ankle) show a swap: the shoulders'
# and hips' centres move with the torso, so they tell the heading, not which limb is which
SWAP_PAIRS: dict[str, tuple[tuple[int, ...], tuple[int, ...]]] = {
    pair: (
        tuple(PART_NAMES.index(f'{p}_l') for p in parts),
        tuple(PART_NAMES.index(f'{p}_r') for p in parts),
    )
    for pair, parts in (('arms', ('forearm', 'hand')), ('legs', ('shank', 'foot')))
}
SETTLE_S = 1.0  # the heading's worst error is also given from this long after the first frame


@dataclass
class FrameErrors:
    """Errors of matched frames: arrays over (frames, parts)."""

    stamps_ns: np.ndarray  # (F,)
    joint_mm: np.ndarray  # (F, P) joint-centre (part origin) error, mm
    axis_deg: np.ndarray  # (F, P) angle between estimated and true part axes (+z), degrees
    phase: np.ndarray | None  # (F,) gait-phase error modulo 1, or None
    heading_deg: np.ndarray | None = None  # (F,) estimate's heading less the truth's, (-180, 180]
    side_swap: np.ndarray | None = None  # (F, pairs) the pair (SWAP_PAIRS) fits better exchanged

    @property
    def mpjpe_mm(self) -> np.ndarray:
        """Mean joint-centre error of each frame (F,)."""
        return self.joint_mm.mean(axis=1)


def pose_errors(
    true_origins: np.ndarray,
    true_rotations: np.ndarray,
    est_origins: np.ndarray,
    est_rotations: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Joint-centre errors (mm) and axis-direction errors (deg), arrays (..., P)."""
    joint_mm = 1000.0 * np.linalg.norm(est_origins - true_origins, axis=-1)
    est_axis, true_axis = est_rotations[..., :, 2], true_rotations[..., :, 2]
    sin = np.linalg.norm(np.cross(est_axis, true_axis), axis=-1)
    cos = np.sum(est_axis * true_axis, axis=-1)
    return joint_mm, np.degrees(np.arctan2(sin, cos))  # exact 0 for equal axes, unlike arccos


def facing_of_poses(rotations: np.ndarray) -> np.ndarray:
    """Return where the torso's forward (+x) axis points about world z, rad (...,).

    From part rotations (..., P, 3, 3): the figure :func:`anatomy.facing` gives from coordinates.
    """
    forward = np.asarray(rotations)[..., PART_NAMES.index('torso'), :, 0]
    return np.arctan2(forward[..., 1], forward[..., 0])


def heading_error(true_rotations: np.ndarray, est_rotations: np.ndarray) -> np.ndarray:
    """Return the estimate's heading less the truth's in degrees, (-180, 180], per frame."""
    turn = facing_of_poses(est_rotations) - facing_of_poses(true_rotations)
    return np.degrees(np.angle(np.exp(1j * turn)))


def side_swaps(true_origins: np.ndarray, est_origins: np.ndarray) -> np.ndarray:
    """Return, per frame and pair of limbs (SWAP_PAIRS), whether it fits better exchanged (F, 2).

    The mean distance of the pair's elbows and wrists (knees and ankles) to the truth's, as
    labelled and with the estimate's left and right exchanged: a 180-degree turn with the sides
    swapped, or one limb taken for the other, fits better exchanged.
    """
    return pairs_exchanged(est_origins, true_origins, SWAP_PAIRS)


def pairs_exchanged(
    estimate: np.ndarray,
    reference: np.ndarray,
    pairs: Mapping[str, tuple[Sequence[int], Sequence[int]]],
) -> np.ndarray:
    """Return per frame and pair whether the pair fits ``reference`` better exchanged (..., P).

    Each pair is the indices of its left points and of its right ones along the second-to-last
    axis; its fit is the mean distance of those points, NaN points left out (a pair without
    any counts as not exchanged).
    """
    out = []
    for left, right in pairs.values():
        labelled, exchanged = [*left, *right], [*right, *left]
        own = np.linalg.norm(estimate[..., labelled, :] - reference[..., labelled, :], axis=-1)
        other = np.linalg.norm(estimate[..., exchanged, :] - reference[..., labelled, :], axis=-1)
        with warnings.catch_warnings():
            warnings.filterwarnings('ignore', 'Mean of empty slice', RuntimeWarning)
            out.append(np.nanmean(other, axis=-1) < np.nanmean(own, axis=-1))
    return np.stack(out, axis=-1)


def phase_error(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Gait-phase error modulo the cycle, in [0, 0.5]."""
    d = np.mod(np.asarray(estimate) - np.asarray(truth), 1.0)
    return np.minimum(d, 1.0 - d)


def summarize(
    errors: FrameErrors, body_height: float, frames_truth: int, start_ns: int | None = None
) -> dict:
    """Return the summary figures; keys are stable (the ``--json`` contract).

    ``start_ns``: the truth's first stamp (default the first matched one), from which the
    heading's settling time (SETTLE_S) counts.
    """
    have = errors.joint_mm.size > 0
    translation_pct = errors.joint_mm / (10.0 * body_height)  # mm / (1000 * h) * 100
    heading = None if errors.heading_deg is None or not have else np.abs(errors.heading_deg)
    settled = None
    if heading is not None:
        start = int(errors.stamps_ns[0]) if start_ns is None else int(start_ns)
        settled = heading[np.asarray(errors.stamps_ns, np.int64) >= start + int(SETTLE_S * 1e9)]
    swaps = errors.side_swap if have else None
    return {
        'frames': int(len(errors.stamps_ns)),
        'frames_truth': int(frames_truth),
        'frames_missing': int(frames_truth - len(errors.stamps_ns)),
        'body_height_m': float(body_height),
        'mpjpe_mm_mean': float(errors.mpjpe_mm.mean()) if have else None,
        'mpjpe_mm_median': float(np.median(errors.mpjpe_mm)) if have else None,
        'mpjpe_mm_max': float(errors.mpjpe_mm.max()) if have else None,
        'joint_mm_max': float(errors.joint_mm.max()) if have else None,
        'translation_pct_height_max': float(translation_pct.max()) if have else None,
        'axis_deg_mean': float(errors.axis_deg.mean()) if have else None,
        'axis_deg_max': float(errors.axis_deg.max()) if have else None,
        'phase_err_median': float(np.median(errors.phase))
        if errors.phase is not None and have
        else None,
        'phase_err_max': float(errors.phase.max()) if errors.phase is not None and have else None,
        'heading_err_deg_mean': float(heading.mean()) if heading is not None else None,
        'heading_err_deg_max': float(heading.max()) if heading is not None else None,
        'heading_err_deg_max_after_1s': float(settled.max())
        if settled is not None and settled.size
        else None,
        'frames_side_swap': int(swaps.any(axis=1).sum()) if swaps is not None else None,
        **{
            f'frames_side_swap_{pair}': int(swaps[:, k].sum()) if swaps is not None else None
            for k, pair in enumerate(SWAP_PAIRS)
        },
    }


def per_part_table(errors: FrameErrors, part_names, body_height: float) -> list[dict]:
    """One row per part: its joint, translation and axis errors.

    Mean/max joint error (mm), max translation (% height), mean/max axis error (deg).
    """
    rows = []
    for i, name in enumerate(part_names):
        if errors.joint_mm.size == 0:
            break
        rows.append(
            {
                'part': name,
                'joint_mm_mean': float(errors.joint_mm[:, i].mean()),
                'joint_mm_max': float(errors.joint_mm[:, i].max()),
                'translation_pct_height_max': float(
                    errors.joint_mm[:, i].max() / (10.0 * body_height)
                ),
                'axis_deg_mean': float(errors.axis_deg[:, i].mean()),
                'axis_deg_max': float(errors.axis_deg[:, i].max()),
            }
        )
    return rows
