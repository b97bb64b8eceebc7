"""Rohr's figures for a walker run.

``memo-ros evaluate --plots`` when the estimate has walker measurements.

- ``walker_estimates.png`` (Fig. 26): X, Y and pose over the frame number; left the per-frame
  grid-search
  measurements (``/memo/walker/measurement``), right the Kalman estimates, each with the truth;
- ``walker_contours.png`` (Fig. 27): the visible model contours of the estimate over four camera
  images;
- ``similarity_curve.png`` (Fig. 19): s(p) over the whole cycle with the 3D position fixed at the
  estimate,
  for one frame whose edge lines are recomputed from its image with the studio's contour_node
  settings.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

MEASUREMENT_TOPIC = '/memo/walker/measurement'
CONTOUR_FRAMES = 4
CONTOUR_BGR = (0, 255, 255)


def has_walker_measurements(topics: dict[str, str]) -> bool:
    """Whether an estimate bag carries the walker's per-frame measurements."""
    return MEASUREMENT_TOPIC in topics


def write_walker_plots(
    directory: str | Path, estimate_bag: Path, truth, estimate, body, studio, truth_bag: Path
) -> list[Path]:
    """Write the walker's figures into ``directory``; return their paths."""
    import matplotlib

    matplotlib.use('Agg')
    from memo_ros.ros.bagio import read_messages, stamp_to_ns

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    measured = {
        stamp_to_ns(m.message.header.stamp): dict(zip(m.message.name, m.message.position))
        for m in read_messages(estimate_bag, [MEASUREMENT_TOPIC])
    }
    truth_stamps = np.array(sorted(truth.origins), dtype=np.int64)
    paths = [
        _estimates_figure(
            directory / 'walker_estimates.png', measured, truth, estimate, body, truth_stamps
        )
    ]
    if studio is not None and estimate.origins:
        paths.append(
            _contours_figure(
                directory / 'walker_contours.png', estimate, body, studio, truth_bag, truth_stamps
            )
        )
        curve = _similarity_figure(
            directory / 'similarity_curve.png',
            truth,
            estimate,
            body,
            studio,
            truth_bag,
            truth_stamps,
        )
        if curve is not None:
            paths.append(curve)
    return paths


def _frame(stamps, truth_stamps: np.ndarray) -> np.ndarray:
    """Index of each stamp among the truth frames."""
    return np.searchsorted(truth_stamps, np.asarray(list(stamps), dtype=np.int64))


def _vertical_offset(body, joints: dict[int, dict[str, float]], stamps) -> np.ndarray:
    """Y.

    The pelvis height minus the walking model's vertical displacement at the frame's gait phase.
    """
    from memo_ros.core.walking.gait import WalkingModel

    walking = WalkingModel(body)
    return np.array(
        [
            joints[s]['root_tz'] - float(walking.pelvis_height(joints[s]['gait_phase']))
            for s in stamps
        ]
    )


def _estimates_figure(
    path: Path, measured: dict, truth, estimate, body, truth_stamps: np.ndarray
) -> Path:
    import matplotlib.pyplot as plt

    m_stamps = sorted(measured)
    e_stamps = sorted(s for s in estimate.joints if 'gait_phase' in estimate.joints[s])
    t_frames = np.arange(len(truth_stamps))
    t_x = np.array([truth.joints[s]['root_tx'] for s in truth_stamps])
    t_y = _vertical_offset(body, truth.joints, truth_stamps)
    t_pose = np.array([truth.joints[s]['gait_phase'] for s in truth_stamps])
    series = {
        'measurements': (
            _frame(m_stamps, truth_stamps),
            [measured[s]['X'] for s in m_stamps],
            [measured[s]['Y'] for s in m_stamps],
            [measured[s]['pose'] for s in m_stamps],
        ),
        'Kalman filter estimates': (
            _frame(e_stamps, truth_stamps),
            [estimate.joints[s]['root_tx'] for s in e_stamps],
            _vertical_offset(body, estimate.joints, e_stamps),
            [estimate.joints[s]['gait_phase'] for s in e_stamps],
        ),
    }
    fig, axes = plt.subplots(3, 2, figsize=(9.0, 7.0), sharex=True)
    for col, (title, (frames, x, y, pose)) in enumerate(series.items()):
        for row, (label, values, true) in enumerate(
            (('X (m)', x, t_x), ('Y (m)', y, t_y), ('pose (cycle)', pose, t_pose))
        ):
            ax = axes[row, col]
            shown_true = (
                np.where(np.abs(np.diff(true, prepend=true[:1])) > 0.5, np.nan, true)
                if row == 2
                else true
            )
            ax.plot(t_frames, shown_true, '-', color='tab:blue', lw=1.0, label='truth')
            ax.plot(frames, values, 'o', color='tab:red', ms=2.5, label=title)
            ax.set_ylabel(label, fontsize=8)
            ax.tick_params(labelsize=7)
            ax.grid(alpha=0.3)
        axes[0, col].set_title(title, fontsize=9)
        axes[0, col].legend(fontsize=6, loc='best')
        axes[2, col].set_xlabel('frame', fontsize=8)
    fig.suptitle('walker: X, Y, pose over the frame number (Rohr Fig. 26)', fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def _contours_figure(
    path: Path, estimate, body, studio, truth_bag: Path, truth_stamps: np.ndarray
) -> Path:
    """Visible model contours of the estimate on four images, cropped around the walker.

    Side by side.
    """
    import cv2

    from memo_ros.core.walking.model_contours import visible_contours
    from memo_ros.tools.plots import _read_images

    camera = studio.cameras[0]
    stamps = np.array(sorted(estimate.origins), dtype=np.int64)
    picks = stamps[
        np.unique(np.linspace(0, len(stamps) - 1, CONTOUR_FRAMES + 2).round().astype(int))[1:-1]
    ]
    images = _read_images(truth_bag, [camera.name], {int(s) for s in picks})
    tiles = []
    for stamp in picks:
        grey = images.get((camera.name, int(stamp)))
        if grey is None:
            continue
        rotations, origins = estimate.rotations[int(stamp)], estimate.origins[int(stamp)]
        contours, rendering = visible_contours(
            camera, rotations, origins, body.semi_axes, body.lengths
        )
        a, b = contours.project(camera)
        image = cv2.cvtColor(np.ascontiguousarray(grey), cv2.COLOR_GRAY2BGR)
        zoom = 2
        ys, xs = np.nonzero(rendering.label)
        x0, x1 = max(xs.min() - 25, 0), min(xs.max() + 25, grey.shape[1])
        y0, y1 = max(ys.min() - 15, 0), min(ys.max() + 15, grey.shape[0])
        tile = cv2.resize(
            image[y0:y1, x0:x1], None, fx=zoom, fy=zoom, interpolation=cv2.INTER_NEAREST
        )
        for p, q in zip(a[0], b[0]):
            start = tuple(int(v) for v in np.rint((p - [x0, y0] + 0.5) * zoom))
            end = tuple(int(v) for v in np.rint((q - [x0, y0] + 0.5) * zoom))
            cv2.line(tile, start, end, CONTOUR_BGR, 1, cv2.LINE_AA)
        frame = int(np.searchsorted(truth_stamps, stamp))
        cv2.putText(
            tile,
            f'frame {frame}',
            (4, 14),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.45,
            (0, 0, 255),
            1,
            cv2.LINE_AA,
        )
        tiles.append(tile)
    height = max(t.shape[0] for t in tiles)
    row = np.hstack([np.pad(t, ((0, height - t.shape[0]), (0, 4), (0, 0))) for t in tiles])
    cv2.imwrite(str(path), row)
    return path


def _similarity_figure(
    path: Path, truth, estimate, body, studio, truth_bag: Path, truth_stamps: np.ndarray
) -> Path | None:
    """s(p) over the whole cycle at the estimate's 3D position for the middle estimated frame.

    Fig. 19.
    """
    import matplotlib.pyplot as plt

    from memo_ros.core.vision.contours import ContourPipeline
    from memo_ros.core.walking.search import WalkerModel
    from memo_ros.core.walking.similarity import edge_table
    from memo_ros.nodes.contour_node import pipeline_settings
    from memo_ros.ros.bagio import grey_images

    camera = studio.cameras[0]
    stamps = sorted(s for s in estimate.joints if 'gait_phase' in estimate.joints[s])
    if not stamps:
        return None
    stamp = stamps[len(stamps) // 2]
    pipeline = ContourPipeline(pipeline_settings(studio.node_parameters.get('contour_node', {})))
    edges = None
    for image_stamp, grey in grey_images(truth_bag, f'/{camera.name}/image_raw'):
        result = pipeline.process(grey)
        if image_stamp == stamp:
            edges = result.edges
            break
    if edges is None or len(edges) == 0:
        return None
    model = WalkerModel(body, camera)
    joints = estimate.joints[stamp]
    offset = joints['root_tz'] - float(model.walking.pelvis_height(joints['gait_phase']))
    poses = np.arange(0.0, 1.0, 0.01)
    found = model.search(
        edge_table(edges),
        joints['root_tx'],
        offset,
        joints['root_ty'],
        poses,
        np.zeros(1),
        np.zeros(1),
        heading=float(
            np.arctan2(estimate.rotations[stamp][0][1, 0], estimate.rotations[stamp][0][0, 0])
        ),
    )
    fig, ax = plt.subplots(figsize=(6.0, 3.0))
    ax.plot(poses, found.curve, '-', color='tab:red', lw=1.2)
    ax.axvline(joints['gait_phase'], color='tab:green', ls='--', lw=1.0, label='estimated pose')
    if 'gait_phase' in truth.joints.get(stamp, {}):
        ax.axvline(
            truth.joints[stamp]['gait_phase'], color='tab:blue', ls=':', lw=1.0, label='true pose'
        )
    frame = int(np.searchsorted(truth_stamps, stamp))
    ax.set_xlabel('pose (cycle)', fontsize=8)
    ax.set_ylabel('similarity s(p)', fontsize=8)
    ax.set_title(
        f'similarity over the cycle, 3D position fixed, frame {frame} (Rohr Fig. 19)', fontsize=9
    )
    ax.legend(fontsize=7)
    ax.tick_params(labelsize=7)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
