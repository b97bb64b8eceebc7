"""A tracked body against an independent keypoint reference: which side is which, and joint errors.

The reference is a learned 2D body-keypoint detector's output triangulated
over the calibrated cameras (:mod:`memo_ros.core.evaluation.triangulation`).
It knows a person's left from right and front from back, which silhouettes
cannot tell; it is not ground truth: its joints are the detector's idea of a
joint (a hip keypoint is not the model's hip centre), and it carries the
detector's and the calibration's errors.  Hence three joint errors: raw,
with each joint's mean offset over the sequence removed (definitions differ),
and after a per-frame similarity (Procrustes) alignment.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from memo_ros.core.evaluation.metrics import pairs_exchanged
from memo_ros.core.geometry.body import PART_NAMES, other_side

# the model's joint centres compared (part origins) and the keypoints standing for them
JOINTS: tuple[str, ...] = (
    'shoulder_l',
    'shoulder_r',
    'elbow_l',
    'elbow_r',
    'wrist_l',
    'wrist_r',
    'hip_l',
    'hip_r',
    'knee_l',
    'knee_r',
    'ankle_l',
    'ankle_r',
)
MODEL_PART = {  # joint -> the part whose origin is that joint's centre
    'shoulder_l': 'upper_arm_l',
    'shoulder_r': 'upper_arm_r',
    'elbow_l': 'forearm_l',
    'elbow_r': 'forearm_r',
    'wrist_l': 'hand_l',
    'wrist_r': 'hand_r',
    'hip_l': 'thigh_l',
    'hip_r': 'thigh_r',
    'knee_l': 'shank_l',
    'knee_r': 'shank_r',
    'ankle_l': 'foot_l',
    'ankle_r': 'foot_r',
}
# BlazePose's 33 landmarks (mediapipe): the subject's own left and right
BLAZEPOSE = {
    'nose': 0,
    'shoulder_l': 11,
    'shoulder_r': 12,
    'elbow_l': 13,
    'elbow_r': 14,
    'wrist_l': 15,
    'wrist_r': 16,
    'hip_l': 23,
    'hip_r': 24,
    'knee_l': 25,
    'knee_r': 26,
    'ankle_l': 27,
    'ankle_r': 28,
}
SWAP = [JOINTS.index(other_side(j)) for j in JOINTS]  # each joint's twin on the other side
# each pair of limbs whose joints show one limb taken for the other: metrics.SWAP_PAIRS' joints
LIMB_PAIRS: dict[str, tuple[list[int], list[int]]] = {
    pair: ([JOINTS.index(f'{j}_l') for j in joints], [JOINTS.index(f'{j}_r') for j in joints])
    for pair, joints in (('arms', ('elbow', 'wrist')), ('legs', ('knee', 'ankle')))
}


BODY_AXES = ('forward', 'left', 'up')  # the reference body's frame of a joint's mean offset


def model_joints(origins: np.ndarray) -> np.ndarray:
    """Return the compared joint centres (..., 12, 3) from part origins (..., 14, 3)."""
    return origins[..., [PART_NAMES.index(MODEL_PART[j]) for j in JOINTS], :]


def heading(joints: np.ndarray) -> np.ndarray:
    """Return where a body faces about world z, rad (...,).

    Across the hips and shoulders, right to left, x up.
    """
    left = joints[..., [JOINTS.index('hip_l'), JOINTS.index('shoulder_l')], :].mean(-2)
    right = joints[..., [JOINTS.index('hip_r'), JOINTS.index('shoulder_r')], :].mean(-2)
    across = left - right
    forward = np.stack([across[..., 1], -across[..., 0]], -1)  # (left - right) x z, horizontal
    return np.arctan2(forward[..., 1], forward[..., 0])


def procrustes(
    estimate: np.ndarray, reference: np.ndarray, weight: np.ndarray | None = None
) -> np.ndarray:
    """Return ``estimate`` (..., J, 3) best aligned to ``reference`` by a similarity transform.

    Rotation (no reflection), translation and one isotropic scale, per leading
    index (frame), fitted by weighted least squares (Umeyama); joints of weight
    0 (missing) do not count but are moved too.
    """
    if weight is None:
        weight = np.ones(estimate.shape[:-1])
    w = weight[..., None] / np.maximum(weight.sum(-1), 1e-12)[..., None, None]
    mu_e = (w * estimate).sum(-2, keepdims=True)
    mu_r = (w * reference).sum(-2, keepdims=True)
    e, r = estimate - mu_e, reference - mu_r
    u, s, vt = np.linalg.svd(np.swapaxes(w * e, -1, -2) @ r)
    d = np.sign(np.linalg.det(u @ vt))
    fix = np.ones(s.shape)
    fix[..., 2] = np.where(d == 0, 1.0, d)
    rotation = u @ (fix[..., :, None] * vt)
    scale = (s * fix).sum(-1) / np.maximum((w * e**2).sum((-1, -2)), 1e-12)
    return scale[..., None, None] * e @ rotation + mu_r


@dataclass
class KeypointComparison:
    """Per frame and joint errors (mm) of a track against the reference, and side checks."""

    raw_mm: np.ndarray  # (F, J)
    offset_removed_mm: np.ndarray  # (F, J)
    procrustes_mm: np.ndarray  # (F, J)
    swapped_mm: np.ndarray  # (F,) mean raw error with the model's left and right exchanged
    turned: np.ndarray  # (F,) bool: the whole body fits better with its sides exchanged
    limbs_swapped: np.ndarray  # (F, pairs) bool: a pair (LIMB_PAIRS) fits better exchanged
    heading_error_deg: np.ndarray  # (F,) signed, in (-180, 180]
    # (J, 3) each joint's mean offset from the reference in the reference body's frame, mm:
    # forward, to its left, up.  What offset removal takes away: a constant one is a different
    # definition of the joint (a model's hip centre against a keypoint's hip), not a tracking error
    body_offset_mm: np.ndarray

    @property
    def sides_agree(self) -> np.ndarray:
        """Return per frame whether the body and each pair of limbs are on the right sides."""
        return ~self.turned & ~self.limbs_swapped.any(axis=1)

    def summary(self) -> dict:
        """Return the figures a user reads: means per joint and overall, side and heading counts.

        Means skip missing joints and frames.
        """
        per_joint = {
            name: {
                'raw_mm': float(np.nanmean(self.raw_mm[:, k])),
                'offset_removed_mm': float(np.nanmean(self.offset_removed_mm[:, k])),
                'procrustes_mm': float(np.nanmean(self.procrustes_mm[:, k])),
                **{
                    f'offset_{axis}_mm': float(self.body_offset_mm[k, i])
                    for i, axis in enumerate(BODY_AXES)
                },
            }
            for k, name in enumerate(JOINTS)
        }
        frames = len(self.sides_agree)
        return {
            'frames': frames,
            'mpjpe_raw_mm': float(np.nanmean(self.raw_mm)),
            'mpjpe_offset_removed_mm': float(np.nanmean(self.offset_removed_mm)),
            'mpjpe_procrustes_mm': float(np.nanmean(self.procrustes_mm)),
            'mpjpe_sides_swapped_mm': float(np.nanmean(self.swapped_mm)),
            'frames_sides_agree': int(self.sides_agree.sum()),
            'frames_sides_disagree': int(frames - self.sides_agree.sum()),
            'frames_turned': int(self.turned.sum()),
            **{
                f'frames_{pair}_swapped': int(self.limbs_swapped[:, k].sum())
                for k, pair in enumerate(LIMB_PAIRS)
            },
            'heading_error_deg_median': float(np.nanmedian(np.abs(self.heading_error_deg))),
            'heading_error_deg_max': float(np.nanmax(np.abs(self.heading_error_deg))),
            'per_joint': per_joint,
        }


def compare(estimate: np.ndarray, reference: np.ndarray) -> KeypointComparison:
    """Compare model joints (F, 12, 3) with reference joints (F, 12, 3), metres.

    Reference joints are NaN where missing.
    """
    raw = np.linalg.norm(estimate - reference, axis=-1) * 1000.0
    swapped = np.linalg.norm(estimate[:, SWAP] - reference, axis=-1) * 1000.0
    offset = np.nanmean(estimate - reference, axis=0)
    offset_removed = np.linalg.norm(estimate - offset - reference, axis=-1) * 1000.0
    ok = np.all(np.isfinite(reference), -1) & np.all(np.isfinite(estimate), -1)  # (F, J)
    fitted = procrustes(
        np.where(ok[..., None], estimate, 0.0), np.where(ok[..., None], reference, 0.0), ok * 1.0
    )
    aligned = np.linalg.norm(fitted - reference, axis=-1) * 1000.0
    aligned[~ok | (ok.sum(1) < 4)[:, None]] = np.nan  # a similarity needs 4 joints to say much
    with np.errstate(invalid='ignore'):
        raw_mean = np.nanmean(np.where(np.isfinite(raw), raw, np.nan), axis=1)
        swapped_mean = np.nanmean(swapped, axis=1)
    turn = heading(estimate) - heading(reference)
    return KeypointComparison(
        raw,
        offset_removed,
        aligned,
        swapped_mean,
        ~(raw_mean < swapped_mean),
        pairs_exchanged(estimate, reference, LIMB_PAIRS),
        np.degrees(np.angle(np.exp(1j * turn))),
        body_offset(estimate, reference),
    )


def body_offset(estimate: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Return each joint's mean offset (J, 3) of ``estimate`` from ``reference``, mm.

    In the reference body's frame of each frame (BODY_AXES: forward along its heading, to its
    left, up); frames or joints missing in either are skipped.
    """
    facing = heading(reference)  # (F,)
    c, s = np.cos(facing)[:, None], np.sin(facing)[:, None]
    d = estimate - reference  # (F, J, 3)
    local = np.stack([c * d[..., 0] + s * d[..., 1], c * d[..., 1] - s * d[..., 0], d[..., 2]], -1)
    with np.errstate(invalid='ignore'):
        return np.nanmean(local, axis=0) * 1000.0
