"""Accuracy of estimated body poses against ground truth.

Joint-centre error (MPJPE, mm) over the pelvis and the 13 joints, per-part
translation error as a percentage of body height and per-part axis-direction
error in degrees (the figures Kakadiaris & Metaxas §5 report: 1 % translation,
2 % orientation), and the gait-phase error modulo the cycle for walking.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class FrameErrors:
    """Errors of matched frames: arrays over (frames, parts)."""

    stamps_ns: np.ndarray  # (F,)
    joint_mm: np.ndarray  # (F, P) joint-centre (part origin) error, mm
    axis_deg: np.ndarray  # (F, P) angle between estimated and true part axes (+z), degrees
    phase: np.ndarray | None  # (F,) gait-phase error modulo 1, or None

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


def phase_error(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Gait-phase error modulo the cycle, in [0, 0.5]."""
    d = np.mod(np.asarray(estimate) - np.asarray(truth), 1.0)
    return np.minimum(d, 1.0 - d)


def summarize(errors: FrameErrors, body_height: float, frames_truth: int) -> dict:
    """Return the summary figures; keys are stable (the ``--json`` contract)."""
    have = errors.joint_mm.size > 0
    translation_pct = errors.joint_mm / (10.0 * body_height)  # mm / (1000 * h) * 100
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
