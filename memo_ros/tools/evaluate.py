"""Score estimated body poses against ground truth, matching frames by header stamp, or without it.

Truth comes from ``/memo/truth/body_poses`` and ``/memo/truth/joint_states``;
the estimate from ``/memo/body_poses`` and ``/memo/joint_states`` (or, for a
bag holding only truth, its truth topics).  Prints per-part and summary errors,
``--json`` one object, ``--plots DIR`` PNG plots and overlays.

A real recording has no truth: ``--images BAG`` (the recording) scores the
track by the silhouette IoU, per camera and frame, between the model rendered
into each camera and the person segmented there as the contour nodes did it,
and counts the frames lost after the track started
(:mod:`memo_ros.tools.silhouette_eval`); ``--plots`` then writes the model
over every camera's image.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
import json
from pathlib import Path

import numpy as np

from memo_ros.core.evaluation.metrics import (
    SWAP_PAIRS,
    FrameErrors,
    heading_error,
    per_part_table,
    phase_error,
    pose_errors,
    side_swaps,
    summarize,
)
from memo_ros.core.geometry.body import PART_NAMES, load_default_body
from memo_ros.core.geometry.rotations import quat_to_matrix
from memo_ros.ros.bagio import bag_topics, read_messages, stamp_to_ns

ESTIMATE_TOPICS = ('/memo/body_poses', '/memo/joint_states')
TRUTH_TOPICS = ('/memo/truth/body_poses', '/memo/truth/joint_states')


@dataclass
class PoseTrack:
    """Poses and joint states of one bag, keyed by header stamp (ns)."""

    origins: dict[int, np.ndarray]
    rotations: dict[int, np.ndarray]
    joints: dict[int, dict[str, float]]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare this command's arguments and options."""
    parser.add_argument('--truth', type=Path, help="bag with /memo/truth/* (the simulator's)")
    parser.add_argument(
        '--estimate',
        required=True,
        type=Path,
        help='bag with /memo/body_poses and /memo/joint_states',
    )
    parser.add_argument(
        '--images',
        type=Path,
        help='the recording (camera images): score by silhouette IoU per '
        'camera and count frames lost, without ground truth (needs --truth or --images or both)',
    )
    parser.add_argument(
        '--keypoints',
        action='store_true',
        help='with --images: compare the track with a learned body-keypoint detector '
        "(mediapipe's BlazePose, pip install memo_ros[keypoints]) triangulated over the cameras: "
        'MPJPE raw, offset-removed and Procrustes-aligned, left/right and heading per frame',
    )
    parser.add_argument(
        '--studio',
        type=Path,
        help='studio YAML (body height, cameras for overlays, contour_node '
        'settings); default: TRUTH.yaml beside the truth bag (or IMAGES.yaml), else the shipped '
        'body',
    )
    parser.add_argument('--tolerance-ms', type=float, default=1.0, help='stamp matching tolerance')
    parser.add_argument(
        '--json', action='store_true', help='print one JSON object instead of tables'
    )
    parser.add_argument(
        '--per-frame', type=Path, help='write per-frame errors as CSV to this file'
    )
    parser.add_argument(
        '--plots', type=Path, help='write PNG plots and overlays into this directory'
    )


def run(args: argparse.Namespace) -> int:
    """Run the command with parsed ``args``; return its exit code."""
    from memo_ros.tools.cli import CliError

    if args.keypoints and args.images is None:
        raise CliError('--keypoints needs --images (the recording)')
    if args.truth is None and args.images is None:
        raise CliError('give --truth (simulated bags) or --images (a real recording), or both')
    for name in ('truth', 'estimate', 'images'):
        path = getattr(args, name)
        if path is not None and not path.exists():
            raise CliError(f'no bag at {path} (--{name})')
    if args.keypoints:
        return run_keypoints(args)
    if args.truth is None:
        return run_without_truth(args)
    studio = _find_studio(args.truth, args.studio)
    body = studio.body if studio else load_default_body()
    truth = load_track(args.truth, TRUTH_TOPICS)
    if not truth.origins:
        raise CliError(f'{args.truth} has no {TRUTH_TOPICS[0]} messages')
    topics = bag_topics(args.estimate)
    estimate = load_track(
        args.estimate, ESTIMATE_TOPICS if ESTIMATE_TOPICS[0] in topics else TRUTH_TOPICS
    )
    if not estimate.origins:
        raise CliError(f'{args.estimate} has no {ESTIMATE_TOPICS[0]} (nor truth) messages')
    errors = match_and_measure(truth, estimate, int(args.tolerance_ms * 1e6))
    height = body.standing_height()
    summary = summarize(errors, height, len(truth.origins), min(truth.origins))
    if args.per_frame:
        _write_per_frame(args.per_frame, errors)
    if args.plots:
        from memo_ros.tools.plots import write_plots

        summary['plots'] = [
            str(p)
            for p in write_plots(args.plots, truth, estimate, errors, body, studio, args.truth)
        ]
        from memo_ros.tools.walker_plots import (
            has_walker_measurements,
            write_walker_plots,
        )

        if has_walker_measurements(topics):  # Rohr's walker: Figs. 26, 27 and 19
            summary['plots'] += [
                str(p)
                for p in write_walker_plots(
                    args.plots, args.estimate, truth, estimate, body, studio, args.truth
                )
            ]
    silhouettes = _silhouettes(args, studio, estimate) if args.images is not None else None
    if silhouettes is not None:
        from memo_ros.tools.silhouette_eval import silhouette_summary

        summary['silhouettes'] = silhouette_summary(silhouettes)
    if args.json:
        print(json.dumps(summary))
        return 0
    print_report(summary, per_part_table(errors, PART_NAMES, height))
    if silhouettes is not None:
        from memo_ros.tools.silhouette_eval import print_silhouette_report

        print()
        print_silhouette_report(silhouettes)
    return 0


def run_without_truth(args: argparse.Namespace) -> int:
    """Silhouette IoU per camera, frames lost, overlays: the score of a real recording."""
    from memo_ros.tools.cli import CliError
    from memo_ros.tools.silhouette_eval import (
        print_silhouette_report,
        silhouette_summary,
        write_per_frame,
    )

    studio = _find_studio(args.images, args.studio)
    if studio is None:
        raise CliError(
            f'no studio for {args.images}: give --studio (cameras are needed to render the model)'
        )
    estimate = load_track(args.estimate, ESTIMATE_TOPICS)
    if not estimate.origins:
        raise CliError(
            f'{args.estimate} has no {ESTIMATE_TOPICS[0]} messages: nothing was tracked'
        )
    report = _silhouettes(args, studio, estimate)
    summary = silhouette_summary(report)
    if args.per_frame:
        write_per_frame(args.per_frame, report)
    if args.plots:
        from memo_ros.tools.plots import write_silhouette_plots

        summary['plots'] = [str(p) for p in write_silhouette_plots(args.plots, report)]
    if args.json:
        print(json.dumps(summary))
        return 0
    print_silhouette_report(report)
    if summary.get('plots'):
        print(f'{"plots":<28} {len(summary["plots"])} files in {Path(summary["plots"][0]).parent}')
    return 0


def run_keypoints(args: argparse.Namespace) -> int:
    """Score a track of a real recording against a learned-keypoint reference."""
    from memo_ros.tools.cli import CliError
    from memo_ros.tools.keypoint_eval import (
        cache_path,
        evaluate_keypoints,
        print_keypoint_report,
        write_keypoint_per_frame,
        write_keypoint_plots,
    )
    from memo_ros.tools.keypoints import KeypointsUnavailable

    studio = _find_studio(args.images, args.studio)
    if studio is None:
        raise CliError(f'no studio for {args.images}: give --studio (the calibrated cameras)')
    estimate = load_track(args.estimate, ESTIMATE_TOPICS)
    if not estimate.origins:
        raise CliError(
            f'{args.estimate} has no {ESTIMATE_TOPICS[0]} messages: nothing was tracked'
        )
    try:
        report = evaluate_keypoints(
            args.images, estimate.origins, studio, cache_path(args.estimate)
        )
    except (KeypointsUnavailable, ValueError) as exc:
        raise CliError(str(exc)) from None
    summary = report.summary()
    if args.per_frame:
        write_keypoint_per_frame(args.per_frame, report)
    if args.plots:
        summary['plots'] = [str(p) for p in write_keypoint_plots(args.plots, report)]
    if args.json:
        print(json.dumps(summary))
        return 0
    print_keypoint_report(report)
    return 0


def _silhouettes(args: argparse.Namespace, studio, estimate):
    """Return the silhouette report of ``estimate``.

    Against the person segmented in ``args.images``.
    """
    from memo_ros.tools.cli import CliError
    from memo_ros.tools.silhouette_eval import (
        evaluate_silhouettes,
        frame_outcomes,
        model_shape,
    )

    if studio is None:
        raise CliError('--images needs a studio (--studio) for the cameras')
    return evaluate_silhouettes(
        args.images,
        estimate,
        frame_outcomes(args.estimate),
        studio,
        model_shape(args.estimate, studio.body),
    )


def load_track(path: Path, topics: tuple[str, str]) -> PoseTrack:
    """Read body poses and joint states of ``topics`` from a bag."""
    track = PoseTrack({}, {}, {})
    for m in read_messages(path, list(topics)):
        stamp = stamp_to_ns(m.message.header.stamp)
        if m.topic == topics[0]:
            poses = m.message.poses
            if len(poses) != len(PART_NAMES):
                continue
            track.origins[stamp] = np.array(
                [[p.position.x, p.position.y, p.position.z] for p in poses]
            )
            track.rotations[stamp] = quat_to_matrix(
                np.array(
                    [
                        [p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w]
                        for p in poses
                    ]
                )
            )
        else:
            track.joints[stamp] = dict(zip(m.message.name, m.message.position))
    return track


def match_and_measure(truth: PoseTrack, estimate: PoseTrack, tolerance_ns: int) -> FrameErrors:
    """Measure the estimate against the truth, frame by frame.

    Every truth frame is paired with the estimate of the nearest stamp within the tolerance.
    """
    est_stamps = np.array(sorted(estimate.origins), dtype=np.int64)
    pairs = []
    for stamp in sorted(truth.origins):
        k = int(np.searchsorted(est_stamps, stamp))
        candidates = [i for i in (k - 1, k) if 0 <= i < len(est_stamps)]
        if not candidates:
            continue
        best = int(est_stamps[min(candidates, key=lambda i: abs(int(est_stamps[i]) - stamp))])
        if abs(best - stamp) <= tolerance_ns:
            pairs.append((stamp, best))
    if not pairs:
        return FrameErrors(
            np.zeros(0, np.int64),
            np.zeros((0, len(PART_NAMES))),
            np.zeros((0, len(PART_NAMES))),
            None,
        )
    t_o = np.stack([truth.origins[t] for t, _ in pairs])
    t_r = np.stack([truth.rotations[t] for t, _ in pairs])
    e_o = np.stack([estimate.origins[e] for _, e in pairs])
    e_r = np.stack([estimate.rotations[e] for _, e in pairs])
    joint_mm, axis_deg = pose_errors(t_o, t_r, e_o, e_r)
    phase = None
    if all(
        'gait_phase' in truth.joints.get(t, {}) and 'gait_phase' in estimate.joints.get(e, {})
        for t, e in pairs
    ):
        phase = phase_error(
            [estimate.joints[e]['gait_phase'] for _, e in pairs],
            [truth.joints[t]['gait_phase'] for t, _ in pairs],
        )
    return FrameErrors(
        np.array([t for t, _ in pairs]),
        joint_mm,
        axis_deg,
        phase,
        heading_error(t_r, e_r),
        side_swaps(t_o, e_o),
    )


def print_report(summary: dict, parts: list[dict]) -> None:
    """Human-readable tables: per part, then the summary."""
    print(
        f'{"part":<12} {"joint mean mm":>13} {"joint max mm":>12} {"transl max %h":>13} '
        f'{"axis mean deg":>13} {"axis max deg":>12}'
    )
    for row in parts:
        print(
            f'{row["part"]:<12} {row["joint_mm_mean"]:>13.1f} {row["joint_mm_max"]:>12.1f} '
            f'{row["translation_pct_height_max"]:>13.2f} {row["axis_deg_mean"]:>13.2f} '
            f'{row["axis_deg_max"]:>12.2f}'
        )
    print()
    for key, value in summary.items():
        if key in ('plots', 'silhouettes'):
            continue
        text = (
            'n/a'
            if value is None
            else (f'{value:.3f}' if isinstance(value, float) else str(value))
        )
        print(f'{key:<28} {text}')
    if summary.get('plots'):
        print(
            f'plots                        {len(summary["plots"])} files in '
            f'{Path(summary["plots"][0]).parent}'
        )


def _write_per_frame(path: Path, errors: FrameErrors) -> None:
    header = ['stamp_ns', 'mpjpe_mm', 'joint_mm_max', 'axis_deg_max'] + (
        ['phase_err'] if errors.phase is not None else []
    )
    if errors.heading_deg is not None:
        header.append('heading_err_deg')
    if errors.side_swap is not None:
        header += [f'side_swap_{pair}' for pair in SWAP_PAIRS]
    header += [f'joint_mm_{part}' for part in PART_NAMES]  # which part misses, and when
    lines = [','.join(header)]
    for k, stamp in enumerate(errors.stamps_ns):
        row = [
            str(int(stamp)),
            f'{errors.mpjpe_mm[k]:.3f}',
            f'{errors.joint_mm[k].max():.3f}',
            f'{errors.axis_deg[k].max():.3f}',
        ]
        if errors.phase is not None:
            row.append(f'{errors.phase[k]:.4f}')
        if errors.heading_deg is not None:
            row.append(f'{errors.heading_deg[k]:.3f}')
        if errors.side_swap is not None:
            row += [str(int(v)) for v in errors.side_swap[k]]
        row += [f'{v:.3f}' for v in errors.joint_mm[k]]
        lines.append(','.join(row))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text('\n'.join(lines) + '\n', encoding='utf-8')


def _find_studio(bag: Path, given: Path | None):
    from memo_ros.core.formats.studio import Studio

    if given is not None:
        return Studio.load(given)
    beside = bag.with_name(bag.name + '.yaml')
    return Studio.load(beside) if beside.is_file() else None
