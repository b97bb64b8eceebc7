"""PNG plots of an evaluation.

Joint curves, per-frame errors and model outlines over camera images.

``joint_curves.png`` shows estimated against true generalized coordinates over the frame number
(Rohr Figs. 26, 32-33), ``errors.png`` the per-frame errors, and ``overlay_<cam>_<frame>.png`` the
estimated model's contours drawn on the camera image (Rohr Fig. 27).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from memo_ros.core.evaluation.metrics import FrameErrors

ANGLE_DEG = 180.0 / np.pi
OVERLAY_FRAMES = 4
VARYING_STD = 1e-3
SILHOUETTE_BGR = (0, 255, 255)  # yellow: the outline of the whole estimated body
# one BGR colour per part (internal boundaries): matplotlib's tab10 colours, then light tab20 ones
PART_BGR = (
    (180, 119, 31),
    (14, 127, 255),
    (44, 160, 44),
    (40, 39, 214),
    (189, 103, 148),
    (75, 86, 140),
    (194, 119, 227),
    (127, 127, 127),
    (34, 189, 188),
    (207, 190, 23),
    (232, 199, 174),
    (120, 187, 255),
    (138, 223, 152),
    (150, 152, 255),
)


def write_plots(
    directory: str | Path,
    truth,
    estimate,
    errors: FrameErrors,
    body,
    studio,
    truth_bag: str | Path,
) -> list[Path]:
    """Write joint curves, error curves and (with a studio) image overlays into ``directory``.

    Return the paths.
    """
    import matplotlib

    matplotlib.use('Agg')
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    truth_stamps = np.array(sorted(truth.origins), dtype=np.int64)
    paths = [
        _joint_curves(directory / 'joint_curves.png', truth, estimate, body, truth_stamps),
        _error_curves(directory / 'errors.png', errors, truth_stamps),
    ]
    if studio is not None and len(errors.stamps_ns):
        paths += _overlays(
            directory, estimate, errors, body, studio, Path(truth_bag), truth_stamps
        )
    return paths


# ------------------------------------------------------------------ curves
def _frame_numbers(stamps: np.ndarray, truth_stamps: np.ndarray) -> np.ndarray:
    """Frame number (index in the sorted truth stamps) of the nearest truth frame of each stamp."""
    n = len(truth_stamps)
    if n == 0:
        return np.zeros(len(stamps), int)
    k = np.searchsorted(truth_stamps, stamps)
    lo, hi = np.clip(k - 1, 0, n - 1), np.clip(k, 0, n - 1)
    return np.where(np.abs(stamps - truth_stamps[lo]) <= np.abs(truth_stamps[hi] - stamps), lo, hi)


def _series(joints: dict[int, dict[str, float]], stamps: np.ndarray, name: str) -> np.ndarray:
    """Values of coordinate ``name`` at ``stamps`` (NaN where absent)."""
    return np.array([joints.get(int(s), {}).get(name, np.nan) for s in stamps], float)


def _coordinates_to_plot(truth, body, truth_stamps: np.ndarray) -> list[str]:
    """Coordinates that vary in the truth, plus gait phase and ground position when walking."""
    names = list(body.coordinate_names)
    walking = any('gait_phase' in truth.joints.get(int(s), {}) for s in truth_stamps)
    if walking:
        names.append('gait_phase')
    chosen = []
    for name in names:
        values = _series(truth.joints, truth_stamps, name)
        forced = walking and name in ('gait_phase', 'root_tx', 'root_ty')
        if forced or (np.isfinite(values).any() and np.nanstd(values) > VARYING_STD):
            chosen.append(name)
    return chosen


def _unit(name: str) -> tuple[float, str]:
    """Display factor and unit of a coordinate: metres, cycles or degrees."""
    if name in ('root_tx', 'root_ty', 'root_tz'):
        return 1.0, 'm'
    if name == 'gait_phase':
        return 1.0, 'cycle'
    return ANGLE_DEG, 'deg'


def _break_wraps(x: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Insert NaN where a cyclic value (gait phase) wraps.

    So its line does not jump across the plot.
    """
    jumps = np.flatnonzero(np.abs(np.diff(values)) > 0.5) + 1
    return np.insert(x.astype(float), jumps, np.nan), np.insert(values, jumps, np.nan)


def _joint_curves(path: Path, truth, estimate, body, truth_stamps: np.ndarray) -> Path:
    """Grid of small plots.

    Each varying coordinate's truth (line) and estimate (markers) over the frame.
    """
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    names = _coordinates_to_plot(truth, body, truth_stamps) or ['root_tz']
    cols = int(np.ceil(np.sqrt(len(names))))
    rows = int(np.ceil(len(names) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.0 * cols, 2.2 * rows), squeeze=False)
    frames = np.arange(len(truth_stamps))
    est_stamps = np.array(sorted(estimate.joints), dtype=np.int64)
    est_frames = _frame_numbers(est_stamps, truth_stamps)
    for ax, name in zip(axes.ravel(), names):
        factor, unit = _unit(name)
        true_values = factor * _series(truth.joints, truth_stamps, name)
        est_values = factor * _series(estimate.joints, est_stamps, name)
        x_true = frames.astype(float)
        if name == 'gait_phase':
            x_true, true_values = _break_wraps(x_true, true_values)
        ax.plot(x_true, true_values, '-', color='tab:blue', lw=1.2, label='truth')
        ax.plot(est_frames, est_values, 'o', color='tab:red', ms=2.5, label='estimate')
        ax.set_title(f'{name} ({unit})', fontsize=8)
        ax.tick_params(labelsize=7)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    for ax in axes.ravel()[len(names) :]:
        ax.axis('off')
    axes[0, 0].legend(fontsize=6, loc='best')
    fig.supxlabel('frame', fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def _error_curves(path: Path, errors: FrameErrors, truth_stamps: np.ndarray) -> Path:
    """Per-frame MPJPE (mm), max axis error (deg), heading error (deg) and, when walking.

    Gait-phase error over the frame.
    """
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    frames = _frame_numbers(np.asarray(errors.stamps_ns, np.int64), truth_stamps)
    have = errors.joint_mm.size > 0
    series = [
        ('MPJPE (mm)', errors.mpjpe_mm if have else np.zeros(0)),
        ('max axis error (deg)', errors.axis_deg.max(axis=1) if have else np.zeros(0)),
    ]
    if errors.heading_deg is not None:
        series.append(('heading error (deg)', np.abs(errors.heading_deg)))
    if errors.phase is not None:
        series.append(('gait-phase error (cycle)', np.asarray(errors.phase)))
    panels = len(series)
    fig, axes = plt.subplots(panels, 1, figsize=(7.0, 2.0 * panels), sharex=True, squeeze=False)
    for ax, (label, values) in zip(axes[:, 0], series):
        ax.plot(frames, values, '.-', color='tab:red', lw=1.0, ms=3)
        ax.set_ylabel(label, fontsize=8)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=7)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    axes[-1, 0].set_xlabel('frame', fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


# ---------------------------------------------------------------- overlays
def _overlay_frames(errors: FrameErrors, truth_stamps: np.ndarray) -> dict[int, int]:
    """~4 matched truth stamps evenly spread over the sequence -> their frame numbers."""
    stamps = np.asarray(errors.stamps_ns, np.int64)
    picks = np.unique(
        np.round(np.linspace(0, len(stamps) - 1, min(OVERLAY_FRAMES, len(stamps)))).astype(int)
    )
    chosen = stamps[picks]
    return dict(zip(chosen.tolist(), _frame_numbers(chosen, truth_stamps).tolist()))


def _nearest(stamps: np.ndarray, stamp: int) -> int:
    """Return the element of sorted ``stamps`` nearest to ``stamp``."""
    k = int(np.searchsorted(stamps, stamp))
    candidates = [i for i in (k - 1, k) if 0 <= i < len(stamps)]
    return int(stamps[min(candidates, key=lambda i: abs(int(stamps[i]) - stamp))])


def _read_images(
    bag: Path, cameras: list[str], stamps: set[int]
) -> dict[tuple[str, int], np.ndarray]:
    """Grey images (uint8) of ``cameras`` at header ``stamps``; stops once all are found."""
    from memo_ros.ros.bagio import bag_topics, read_messages, stamp_to_ns
    from memo_ros.ros.images import image_message_to_grey

    available = bag_topics(bag)
    topics = {f'/{c}/image_raw': c for c in cameras if f'/{c}/image_raw' in available}
    wanted = len(topics) * len(stamps)
    images: dict[tuple[str, int], np.ndarray] = {}
    if not wanted:
        return images
    messages = read_messages(bag, list(topics))
    try:
        for m in messages:
            stamp = stamp_to_ns(m.message.header.stamp)
            key = (topics[m.topic], stamp)
            if stamp not in stamps or key in images:
                continue
            images[key] = image_message_to_grey(m.message)
            if len(images) == wanted:
                break
    finally:
        messages.close()
    return images


def outline_image(grey: np.ndarray, label: np.ndarray) -> np.ndarray:
    """BGR copy of ``grey``, each part's outline in its colour, the body silhouette in yellow."""
    import cv2

    image = cv2.cvtColor(np.ascontiguousarray(grey), cv2.COLOR_GRAY2BGR)
    for part in np.unique(label[label > 0]):
        mask = (label == part).astype(np.uint8)
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        cv2.drawContours(image, contours, -1, PART_BGR[(int(part) - 1) % len(PART_BGR)], 1)
    silhouette, _ = cv2.findContours(
        (label > 0).astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE
    )
    cv2.drawContours(image, silhouette, -1, SILHOUETTE_BGR, 1)
    return image


def _overlays(
    directory: Path,
    estimate,
    errors: FrameErrors,
    body,
    studio,
    truth_bag: Path,
    truth_stamps: np.ndarray,
) -> list[Path]:
    """Estimated model outlines over the camera images of ~4 frames.

    One file per camera and frame.
    """
    import cv2

    from memo_ros.core.geometry.render import render

    frames = _overlay_frames(errors, truth_stamps)
    images = _read_images(truth_bag, studio.camera_names, set(frames))
    est_stamps = np.array(sorted(estimate.origins), dtype=np.int64)
    paths = []
    for (cam_name, stamp), grey in sorted(
        images.items(), key=lambda item: (item[0][1], item[0][0])
    ):
        camera = studio.camera(cam_name)
        est = _nearest(est_stamps, stamp)
        scale = grey.shape[1] / camera.width
        rendering = render(
            camera,
            estimate.rotations[est],
            estimate.origins[est],
            body.semi_axes,
            body.lengths,
            scale=scale,
        )
        if rendering.label.shape != grey.shape:
            continue
        image = outline_image(grey, rendering.label)
        cv2.putText(
            image,
            f'{cam_name} frame {frames[stamp]}',
            (4, 14),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.4,
            (0, 0, 255),
            1,
            cv2.LINE_AA,
        )
        path = directory / f'overlay_{cam_name}_{frames[stamp]:04d}.png'
        cv2.imwrite(str(path), image)
        paths.append(path)
    return paths


# ------------------------------------------------------- without ground truth
PERSON_TINT_BGR = (0, 0, 200)  # the segmented person, blended into the image
IOU_COLOURS = ('tab:blue', 'tab:orange', 'tab:green', 'tab:red', 'tab:purple', 'tab:brown')


def silhouette_overlay(
    image: np.ndarray, person: np.ndarray, label: np.ndarray, text: str = ''
) -> np.ndarray:
    """BGR picture.

    The segmented person tinted red, each model part's outline in its colour, the model's
    silhouette in yellow (the two masks the silhouette IoU compares).
    """
    import cv2

    image = np.ascontiguousarray(image)
    bgr = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image[..., :3].copy()
    tinted = bgr.astype(np.float32)
    tinted[person] = 0.55 * tinted[person] + 0.45 * np.array(PERSON_TINT_BGR, np.float32)
    picture = outline_image(np.zeros(bgr.shape[:2], np.uint8), label)
    drawn = picture.any(axis=2)
    out = tinted.astype(np.uint8)
    out[drawn] = picture[drawn]
    if text:
        cv2.putText(
            out, text, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 2, cv2.LINE_AA
        )
        cv2.putText(out, text, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    return out


def write_silhouette_plots(directory: str | Path, report) -> list[Path]:
    """Per kept frame.

    Every camera's overlay and a side-by-side montage; and the IoU curves (iou.png).
    """
    import cv2

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    paths = [_iou_curves(directory / 'iou.png', report)]
    frames = sorted({index for _, index in report.kept})
    for index in frames:
        tiles = []
        for name in report.cameras:
            if (name, index) not in report.kept:
                continue
            image, person, label = report.kept[(name, index)]
            column = report.cameras.index(name)
            iou = report.iou[index, column]
            tile = silhouette_overlay(image, person, label, f'{name} frame {index} IoU {iou:.2f}')
            path = directory / f'overlay_{name}_{index:04d}.png'
            cv2.imwrite(str(path), tile)
            paths.append(path)
            tiles.append(tile)
        if tiles:
            height = max(t.shape[0] for t in tiles)
            montage = np.hstack(
                [np.pad(t, ((0, height - t.shape[0]), (0, 2), (0, 0))) for t in tiles]
            )
            path = directory / f'overlay_{index:04d}.png'
            cv2.imwrite(str(path), montage)
            paths.append(path)
    return paths


def _iou_curves(path: Path, report) -> Path:
    """Silhouette IoU of every camera over the frame number, with the frames not tracked marked."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.0, 2.8))
    frames = np.arange(len(report.stamps))
    for c, name in enumerate(report.cameras):
        mean = report.summary[name]['mean']
        ax.plot(
            frames,
            report.iou[:, c],
            '.-',
            lw=1.0,
            ms=2.5,
            color=IOU_COLOURS[c % len(IOU_COLOURS)],
            label=f'{name} (mean {mean:.2f})',
        )
    untracked = [k for k, o in enumerate(report.outcomes) if o != 'tracking']
    if untracked:
        ax.plot(untracked, np.zeros(len(untracked)), 'x', color='grey', ms=3, label='not tracked')
    ax.axhline(0.7, color='k', lw=0.6, ls='--')
    ax.set_ylim(0.0, 1.0)
    ax.set_xlabel('frame', fontsize=9)
    ax.set_ylabel('silhouette IoU', fontsize=9)
    ax.tick_params(labelsize=7)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6, loc='lower right', ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
