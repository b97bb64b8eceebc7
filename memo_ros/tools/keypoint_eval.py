"""`memo-ros evaluate --keypoints`: a track against a learned-keypoint reference of the recording.

The detector runs on every camera's images (:mod:`memo_ros.tools.keypoints`),
its keypoints are triangulated over the calibrated cameras as Pose2Sim does
(:mod:`memo_ros.core.evaluation.triangulation`), and the track's joint centres
are compared with them (:mod:`memo_ros.core.evaluation.keypoints`).  Reference
points that jump away from their joint's running median (two views agreeing on
the wrong limb) are left out of the errors and counted.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
import warnings

import numpy as np

from memo_ros.core.evaluation.keypoints import (
    BODY_AXES,
    JOINTS,
    LIMB_PAIRS,
    KeypointComparison,
    compare,
    heading,
    model_joints,
)
from memo_ros.core.evaluation.triangulation import (
    Triangulation,
    temporal_outliers,
    triangulate,
)
from memo_ros.tools.keypoints import KEYPOINT_NAMES, Detections, detect

MAX_ERROR_PX = 15.0  # Pose2Sim's default reprojection threshold is 15 px on full-size images
MIN_CONFIDENCE = 0.3
MAX_JUMP_M = 0.25  # from the joint's median over 5 frames: no limb gets there and back so fast


@dataclass
class KeypointReport:
    """The reference, the comparison, and the frames they cover."""

    detections: Detections
    reference: Triangulation
    comparison: KeypointComparison
    stamps: np.ndarray
    nose_in_front: float  # fraction of frames where the reference's nose is ahead of its shoulders
    rejected: np.ndarray  # (F, J) bool: reference points left out as jumps (temporal_outliers)

    def summary(self) -> dict:
        """Return the comparison's figures with the reference's own quality."""
        out = self.comparison.summary()
        error = self.reference.error_px
        out['reference_reprojection_px'] = {
            name: float(np.nanmean(error[:, k])) for k, name in enumerate(JOINTS)
        }
        out['reference_nose_in_front_fraction'] = self.nose_in_front
        out['reference_points'] = int(np.isfinite(self.reference.points[..., 0]).sum())
        out['reference_points_rejected'] = int(self.rejected.sum())
        out['reference_max_reprojection_px'] = MAX_ERROR_PX
        out['reference_max_jump_m'] = MAX_JUMP_M
        out['cameras'] = self.detections.cameras
        return out


def cache_path(estimate: Path) -> Path:
    """Return where the detections of the recording scored against ``estimate`` are kept."""
    return estimate.with_name(estimate.name + '.keypoints.npz')


def evaluate_keypoints(
    images: Path, origins: dict[int, np.ndarray], studio, cache: Path | None
) -> KeypointReport:
    """Detect, triangulate and compare: ``origins`` maps stamps to the track's part origins."""
    detections = detect(images, studio.camera_names, cache)
    stamps = np.array([s for s in detections.stamps if int(s) in origins], np.int64)
    if not len(stamps):
        raise ValueError('no frame of the estimate has images in every camera')
    rows = np.searchsorted(detections.stamps, stamps)
    # the joints and, last, the nose, in one triangulation (each point is solved on its own)
    columns = [KEYPOINT_NAMES.index(j) for j in JOINTS] + [KEYPOINT_NAMES.index('nose')]
    everything = triangulate(
        [studio.camera(c) for c in detections.cameras],
        detections.uv[:, rows][:, :, columns],
        detections.confidence[:, rows][:, :, columns],
        MIN_CONFIDENCE,
        MAX_ERROR_PX,
    )
    reference = Triangulation(
        everything.points[:, :-1], everything.error_px[:, :-1], everything.used[:, :-1]
    )
    nose = everything.points[:, -1]
    estimate = model_joints(np.stack([origins[int(s)] for s in stamps]))
    shoulders = reference.points[:, [JOINTS.index('shoulder_l'), JOINTS.index('shoulder_r')]]
    facing = heading(reference.points)
    ahead = np.einsum(
        'fi,fi->f',
        (nose - shoulders.mean(1))[:, :2],
        np.stack([np.cos(facing), np.sin(facing)], -1),
    )
    seen = np.isfinite(ahead)
    rejected = temporal_outliers(reference.points, max_deviation_m=MAX_JUMP_M)
    return KeypointReport(
        detections,
        reference,
        compare(estimate, np.where(rejected[..., None], np.nan, reference.points)),
        stamps,
        float((ahead[seen] > 0).mean()) if seen.any() else float('nan'),
        rejected,
    )


def print_keypoint_report(report: KeypointReport) -> None:
    """Print the per-joint table and the side and heading figures."""
    s = report.summary()
    print(
        f'{"joint":<12} {"raw mm":>8} {"offset-removed":>15} {"Procrustes":>11} {"ref px":>7}  '
        'mean offset mm: forward / left / up'
    )
    for name in JOINTS:
        j = s['per_joint'][name]
        offset = ' / '.join(f'{j[f"offset_{axis}_mm"]:.0f}' for axis in BODY_AXES)
        print(
            f'{name:<12} {j["raw_mm"]:8.1f} {j["offset_removed_mm"]:15.1f} '
            f'{j["procrustes_mm"]:11.1f} {s["reference_reprojection_px"][name]:7.1f}  {offset}'
        )
    print(
        f'{"all":<12} {s["mpjpe_raw_mm"]:8.1f} {s["mpjpe_offset_removed_mm"]:15.1f} '
        f'{s["mpjpe_procrustes_mm"]:11.1f}'
    )
    print()
    print(f'{"frames":<28} {s["frames"]}')
    print(
        f'{"left/right agree":<28} {s["frames_sides_agree"]} of {s["frames"]} '
        f'(raw MPJPE with the sides swapped: {s["mpjpe_sides_swapped_mm"]:.1f} mm)'
    )
    print(
        f'{"left/right disagree":<28} turned round {s["frames_turned"]}, '
        + ', '.join(f'{pair} swapped {s[f"frames_{pair}_swapped"]}' for pair in LIMB_PAIRS)
        + ' (frames)'
    )
    print(
        f'{"heading error":<28} median {s["heading_error_deg_median"]:.1f} deg, '
        f'max {s["heading_error_deg_max"]:.1f} deg'
    )
    print(
        f'{"reference":<28} BlazePose (full), {len(s["cameras"])} cameras, nose ahead of '
        f'shoulders in {100 * s["reference_nose_in_front_fraction"]:.0f} % of frames'
    )
    print(
        f'{"reference points":<28} {s["reference_points"]}, '
        f'{s["reference_points_rejected"]} left out as jumps (> {MAX_JUMP_M:g} m off a 5-frame '
        'median)'
    )
    print(f'{"reference cameras":<28} a camera over {MAX_ERROR_PX:g} px dropped while > 2 remain')
    print(f'{"Procrustes":<28} per frame: rotation, translation and scale')


def write_keypoint_per_frame(path: Path, report: KeypointReport) -> None:
    """Write one CSV row per frame: stamp, errors, side check, heading error."""
    c = report.comparison
    lines = [
        'stamp_ns,mpjpe_raw_mm,mpjpe_offset_removed_mm,mpjpe_procrustes_mm,'
        'mpjpe_swapped_mm,sides_agree,turned,'
        + ''.join(f'{pair}_swapped,' for pair in LIMB_PAIRS)
        + 'heading_error_deg,reference_reprojection_px,reference_points_rejected'
    ]
    with warnings.catch_warnings():
        warnings.filterwarnings('ignore', 'Mean of empty slice', RuntimeWarning)
        reprojection = np.nanmean(report.reference.error_px, 1)
        rows = np.stack(
            [
                np.nanmean(c.raw_mm, 1),
                np.nanmean(c.offset_removed_mm, 1),
                np.nanmean(c.procrustes_mm, 1),
                c.swapped_mm,
            ],
            1,
        )
    for f, stamp in enumerate(report.stamps):
        lines.append(
            f'{int(stamp)},' + ','.join(f'{v:.2f}' for v in rows[f]) + f',{int(c.sides_agree[f])},'
            f'{int(c.turned[f])},'
            + ''.join(f'{int(v)},' for v in c.limbs_swapped[f])
            + f'{c.heading_error_deg[f]:.2f},{reprojection[f]:.2f},{int(report.rejected[f].sum())}'
        )
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text('\n'.join(lines) + '\n', encoding='utf-8')


def write_keypoint_plots(folder: Path, report: KeypointReport) -> list[Path]:
    """Write per-joint error bars and per-frame errors as PNGs; return their paths."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    folder.mkdir(parents=True, exist_ok=True)
    s = report.summary()
    fig, ax = plt.subplots(figsize=(9, 4))
    x = np.arange(len(JOINTS))
    for k, (key, label) in enumerate(
        [
            ('raw_mm', 'raw'),
            ('offset_removed_mm', 'offset removed'),
            ('procrustes_mm', 'Procrustes'),
        ]
    ):
        ax.bar(x + (k - 1) * 0.27, [s['per_joint'][j][key] for j in JOINTS], 0.27, label=label)
    ax.set_xticks(x, JOINTS, rotation=45, ha='right')
    ax.set_ylabel('error against the keypoint reference, mm')
    ax.legend()
    fig.tight_layout()
    bars = folder / 'keypoints_per_joint.png'
    fig.savefig(bars, dpi=100)
    plt.close(fig)
    c = report.comparison
    fig, ax = plt.subplots(figsize=(9, 4))
    frames = np.arange(len(report.stamps))
    ax.plot(frames, np.nanmean(c.raw_mm, 1), label='raw')
    ax.plot(frames, np.nanmean(c.procrustes_mm, 1), label='Procrustes')
    ax.plot(frames, c.swapped_mm, ':', label='sides swapped (raw)')
    ax.set_xlabel('frame')
    ax.set_ylabel('mean joint error, mm')
    ax.legend()
    fig.tight_layout()
    per_frame = folder / 'keypoints_per_frame.png'
    fig.savefig(per_frame, dpi=100)
    plt.close(fig)
    return [bars, per_frame]
