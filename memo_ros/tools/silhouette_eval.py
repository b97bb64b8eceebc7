"""`memo-ros evaluate` without ground truth.

Silhouette IoU per camera and frames lost, from the bags.

The person is segmented again from the recording's images exactly as the graph's contour nodes did
it (the studio's contour_node parameters, the same background learnt from ``background_bag``, the
tracked body of the previous estimate as the tracked region), the estimated model (its dimensions
from ``/memo/markers``) is rendered into every camera, and the two masks are compared frame by
frame.  ``/memo/processed`` says what became of each frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from memo_ros.core.evaluation.silhouette_score import (
    LostFrames,
    iou_summary,
    lost_after_start,
    silhouette_iou,
)
from memo_ros.core.geometry.body import PART_NAMES, Body
from memo_ros.core.geometry.render import render_labels
from memo_ros.core.vision.contours import ContourPipeline
from memo_ros.core.vision.tracked_region import body_region
from memo_ros.ros.body_messages import (
    MARKERS_TOPIC,
    PROCESSED_TOPIC,
    processed_outcome,
    tracked_body_from_markers,
)
from memo_ros.ros.images import image_message_to_frame, image_message_to_grey


@dataclass
class ModelShape:
    """The tracked body's part dimensions (semi-axes (P, 2), lengths (P,))."""

    semi_axes: np.ndarray
    lengths: np.ndarray


@dataclass
class SilhouetteReport:
    """Per frame and camera IoU (NaN: not tracked), the cameras' summaries, lost frames.

    Kept masks.
    """

    cameras: list[str]
    stamps: np.ndarray  # (F,) image stamps, ns
    iou: np.ndarray  # (F, C)
    summary: dict[str, dict]
    lost: LostFrames
    outcomes: list[str | None]
    kept: dict[tuple[str, int], tuple[np.ndarray, np.ndarray, np.ndarray]] = field(
        default_factory=dict
    )
    # (camera, frame index) -> (image, person mask, model label image) for the overlay frames


def model_shape(estimate: Path, body: Body) -> ModelShape:
    """Return the body the tracker used.

    From its first /memo/markers (one cylinder per part), else ``body``.
    """
    from memo_ros.ros.bagio import bag_topics, read_messages

    if MARKERS_TOPIC in bag_topics(estimate):
        messages = read_messages(estimate, [MARKERS_TOPIC])
        try:
            for m in messages:
                tracked = tracked_body_from_markers(m.message)
                if tracked is None or len(tracked[1][3]) != len(PART_NAMES):
                    continue
                _, _, semi_axes, lengths = tracked[1]
                return ModelShape(semi_axes, lengths)
        finally:
            messages.close()
    return ModelShape(body.semi_axes, body.lengths)


def frame_outcomes(estimate: Path) -> dict[int, str]:
    """Stamp -> outcome of every frame the tracker reported done on /memo/processed."""
    from memo_ros.ros.bagio import bag_topics, read_messages, stamp_to_ns

    if PROCESSED_TOPIC not in bag_topics(estimate):
        return {}
    return {
        stamp_to_ns(m.message.stamp): processed_outcome(m.message.frame_id)
        for m in read_messages(estimate, [PROCESSED_TOPIC])
    }


def _camera_images(images: Path, camera: str, colour: bool) -> list[tuple[int, np.ndarray]]:
    """(stamp, image) of a camera's image_raw in the bag, in order."""
    from memo_ros.ros.bagio import read_messages, stamp_to_ns

    decode = image_message_to_frame if colour else image_message_to_grey
    return [
        (stamp_to_ns(m.message.header.stamp), decode(m.message))
        for m in read_messages(images, [f'/{camera}/image_raw'])
    ]


def _previous(stamps: np.ndarray, stamp: int) -> int | None:
    """Return the newest of the sorted ``stamps`` strictly before ``stamp``."""
    k = int(np.searchsorted(stamps, stamp)) - 1
    return int(stamps[k]) if k >= 0 else None


def evaluate_silhouettes(
    images: Path,
    estimate,
    outcomes: dict[int, str],
    studio,
    shape: ModelShape,
    keep_frames: int = 4,
) -> SilhouetteReport:
    """Segment every camera's images as the contour nodes did and compare with the estimate.

    The estimate is rendered into each camera.
    """
    from memo_ros.nodes.contour_node import (
        PARAMS,
        pipeline_settings,
        recording_background,
    )
    from memo_ros.ros.bagio import tracked_bodies

    params = {q.name: q.default for q in PARAMS} | dict(
        studio.node_parameters.get('contour_node', {})
    )
    settings = pipeline_settings(params)
    colour = settings.segmenter == 'sequence'
    tracked = 'tracked' == settings.keep or colour
    roi_margin = float(params['roi_margin'])
    roi_age = float(params['roi_max_age']) * 1e9
    bag = params['background_bag']
    bodies = (
        tracked_bodies(params['background_track'])
        if colour and bag and params['background_track']
        else None
    )
    est_stamps = np.array(sorted(estimate.origins), dtype=np.int64)
    cameras = studio.camera_names
    per_camera: dict[str, dict[int, float]] = {}
    all_stamps: set[int] = set()
    chosen: set[int] = set()
    kept = {}
    for name in cameras:
        camera = studio.camera(name)
        frames = _camera_images(images, name, colour)
        all_stamps.update(s for s, _ in frames)
        if not chosen and len(est_stamps):
            first = int(np.searchsorted([s for s, _ in frames], est_stamps[0]))
            picks = np.linspace(
                first, len(frames) - 1, min(keep_frames, len(frames) - first)
            ).round()
            chosen = {int(k) for k in picks}
        pipeline = ContourPipeline(settings)
        if colour and bag:
            source = (
                frames
                if Path(bag).resolve() == Path(images).resolve() or not Path(bag).exists()
                else _camera_images(Path(bag), name, colour)
            )
            pipeline.segmenter.method.set_model(
                recording_background(
                    [f for _, f in source], [s for s, _ in source], camera, params, bodies
                )
            )
        scores = per_camera.setdefault(name, {})
        for index, (stamp, image) in enumerate(frames):
            roi = None
            before = _previous(est_stamps, stamp)
            if tracked and before is not None and stamp - before <= roi_age:
                roi = body_region(
                    camera,
                    estimate.rotations[before],
                    estimate.origins[before],
                    shape.semi_axes,
                    shape.lengths,
                    image.shape[:2],
                    roi_margin,
                )
            pipeline.set_roi(roi)
            person = pipeline.process(image).mask
            if stamp not in estimate.origins:
                continue
            view = (
                camera
                if (camera.width, camera.height) == image.shape[1::-1]
                else camera.scaled(image.shape[1] / camera.width)
            )
            label = render_labels(
                view,
                estimate.rotations[stamp],
                estimate.origins[stamp],
                shape.semi_axes,
                shape.lengths,
            ).label
            scores[stamp] = silhouette_iou(label > 0, person)
            if index in chosen:
                kept[(name, index)] = (image, person, label)
    stamps = np.array(sorted(all_stamps), dtype=np.int64)
    iou = np.array([[per_camera[c].get(int(s), np.nan) for c in cameras] for s in stamps]).reshape(
        len(stamps), len(cameras)
    )
    ordered = [outcomes.get(int(s)) for s in stamps]
    return SilhouetteReport(
        cameras, stamps, iou, iou_summary(iou, cameras), lost_after_start(ordered), ordered, kept
    )


def write_per_frame(path: Path, report: SilhouetteReport) -> None:
    """CSV: frame index, stamp, outcome, then each camera's IoU (empty when not tracked)."""
    lines = [','.join(['frame', 'stamp_ns', 'outcome'] + [f'iou_{c}' for c in report.cameras])]
    for k, stamp in enumerate(report.stamps):
        values = ['' if not np.isfinite(v) else f'{v:.4f}' for v in report.iou[k]]
        lines.append(','.join([str(k), str(int(stamp)), report.outcomes[k] or ''] + values))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text('\n'.join(lines) + '\n', encoding='utf-8')


def print_silhouette_report(report: SilhouetteReport) -> None:
    """Return the IoU table per camera, then the frames lost after the first tracked one."""
    print(f'{"camera":<10} {"frames":>6} {"IoU mean":>9} {"median":>7} {"min":>6}')
    for name, row in report.summary.items():
        print(
            f'{name:<10} {row["frames"]:>6} {row["mean"]:>9.3f} {row["median"]:>7.3f} '
            f'{row["min"]:>6.3f}'
        )
    lost = report.lost
    print()
    print(f'{"frames":<28} {len(report.stamps)}')
    print(
        f'{"first tracked frame":<28} '
        f'{"none" if lost.first_tracked is None else lost.first_tracked}'
    )
    reasons = ', '.join(f'{k} {v}' for k, v in lost.reasons.items())
    print(
        f'{"lost after it":<28} {lost.lost} of {lost.after_start}'
        + (f' ({reasons})' if reasons else '')
    )


def silhouette_summary(report: SilhouetteReport) -> dict:
    """Return the --json object."""
    return {
        'frames': int(len(report.stamps)),
        'cameras': report.summary,
        'iou_mean_min_camera': float(
            min((r['mean'] for r in report.summary.values()), default=float('nan'))
        ),
        'first_tracked_frame': report.lost.first_tracked,
        'frames_after_start': report.lost.after_start,
        'frames_lost_after_start': report.lost.lost,
        'lost_reasons': report.lost.reasons,
    }
