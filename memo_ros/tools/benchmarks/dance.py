"""The articulated tracker on studio-dance from 8 headings on two rigs against issue 16's goals.

Every run simulates studio-dance (4 s at 30 Hz: arms overhead, a fast kick of each leg, a full
turn in 1.2 s, a squat) from one start heading on one rig, and tracks it offline with the
ROS-free :class:`ArticulatedTracker` (``TrackerSettings()``), started at the true first pose as
the studio file starts the tracker node, or, with ``--start silhouettes``, from the silhouettes
alone (a studio without ``initial_pose``: the heading searched, then decided by the twin).
Every camera serves every part (no camera selection).
The contours come from the contour pipeline the contour node runs, with its studio settings, on
the simulated grey images (sensor noise, the background learnt from the empty frames first), or,
with ``--contours silhouettes``, from the exact rendered silhouettes.  The dancer is the shipped
average adult or ``--body``; the tracker is given the dancer's body, or with ``--tracker-body
measured`` the average scaled to the measured height, as for a real person.  Per run: MPJPE mean
and max, the heading error's max from 1 s on, frames with a side swap, the tracker's limb
exchanges; then the worst of all runs, and where a run fails, in which time window, during which
moves and in which parts.
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
import multiprocessing
import os
import time
from typing import TYPE_CHECKING, Iterator

import numpy as np

from memo_ros.core.evaluation.metrics import (
    SETTLE_S,
    SWAP_PAIRS,
    heading_error,
    pose_errors,
    side_swaps,
)
from memo_ros.core.geometry.body import PART_NAMES, Body, load_default_body, load_studio_actor
from memo_ros.core.geometry.render import SHAPES, render
from memo_ros.core.multiview.body_estimation import (
    estimate_body,
    frame_silhouettes,
    scaled_body,
)
from memo_ros.core.simulation.scenarios import RIGS, Scenario, dance_moves, make_scenario

if TYPE_CHECKING:
    from memo_ros.core.multiview.tracking import TrackerSettings

HEADINGS_DEG = tuple(range(0, 360, 45))
SIZE = (320, 240)  # half the studio's 640x480: the full sweep in a few minutes on 2 cores
CONTOURS = ('images', 'silhouettes')
STARTS = ('given', 'silhouettes')  # the true first pose, or automatic initialisation
# the tracker's body: the dancer's own, or the shipped average scaled to the height measured from
# the first frame's silhouettes (tracker_node's body_source: silhouettes, as for a real person)
TRACKER_BODIES = ('truth', 'measured')
DEFAULT_BODY = 'config/body_studio_actor.yaml'  # the dancer without --body, as reported
NOISE = 3.0  # grey levels, simulate's default
# issue 16's Done-when for studio-dance
MPJPE_MEAN_MM = 30.0
MPJPE_MAX_MM = 100.0
HEADING_MAX_DEG = 20.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare the dance suite's options (on the benchmark command's parser)."""
    parser.add_argument(
        '--headings',
        default=','.join(str(h) for h in HEADINGS_DEG),
        help='dance: start headings, degrees, comma separated (default 0,45,...,315)',
    )
    parser.add_argument(
        '--rig',
        help=f"dance: {', '.join(RIGS)} or both (default); graph: the simulated bag's rig, "
        f'{" or ".join(RIGS)} (default {RIGS[0]}; ring4 has 4 cameras)',
    )
    parser.add_argument(
        '--size',
        default=f'{SIZE[0]}x{SIZE[1]}',
        help=f'dance: image size WxH (default {SIZE[0]}x{SIZE[1]})',
    )
    parser.add_argument(
        '--contours',
        default='images',
        help='dance: images (the contour pipeline on simulated images, default) or silhouettes '
        '(exact rendered outlines)',
    )
    parser.add_argument(
        '--start',
        default='given',
        help='dance: given (the true first pose, as a studio with initial_pose; default) or '
        'silhouettes (automatic initialisation from the first frame, no pose given)',
    )
    parser.add_argument(
        '--body',
        help="dance: the dancer's body, a body YAML (config/body_average_adult.yaml's format; "
        "default: the simulated studios' actor, config/body_studio_actor.yaml)",
    )
    parser.add_argument(
        '--shape',
        default=SHAPES[0],
        help=f"dance: the dancer's shape as imaged, {' or '.join(SHAPES)} (tapered elliptic "
        "capsules merging over the joints, not the tracker's cylinders); default "
        f'{SHAPES[0]}',
    )
    parser.add_argument(
        '--tracker-body',
        default='truth',
        help="dance: truth (the tracker is given the dancer's body; default) or measured (the "
        "shipped average adult scaled to the height measured from the first frame's "
        'silhouettes, as tracker_node does with body_source: silhouettes)',
    )
    parser.add_argument(
        '--tracker',
        action='append',
        default=[],
        metavar='NAME=VALUE',
        help='dance and tracker: a TrackerSettings field other than its default, e.g. '
        'hold_sigma_px=0 or hold_hull=false (repeatable; default: none, the tracker as it ships)',
    )
    parser.add_argument(
        '--jobs',
        type=int,
        default=min(2, _cpus()),
        help='dance: runs in parallel, one process each (default: 2 or the CPUs, if fewer)',
    )


def dance_rig(args: argparse.Namespace) -> str:
    """Return the dance's ``--rig``: both rigs unless one is named."""
    return 'both' if args.rig is None else args.rig


def command_words(args: argparse.Namespace) -> list[str]:
    """Return this suite's options as command-line words (for the report's command line)."""
    words = ['--headings', args.headings, '--rig', dance_rig(args), '--size', args.size]
    words += ['--contours', args.contours, '--start', args.start, '--jobs', str(args.jobs)]
    if args.body is not None:
        words += ['--body', args.body]
    if args.tracker_body != 'truth':
        words += ['--tracker-body', args.tracker_body]
    if args.shape != SHAPES[0]:
        words += ['--shape', args.shape]
    for setting in args.tracker:
        words += ['--tracker', setting]
    return words + ([] if args.frames is None else ['--frames', str(args.frames)])


def measure(args: argparse.Namespace) -> dict:
    """Return the suite's figures for ``memo-ros benchmark dance`` (user errors as CliError)."""
    from memo_ros.tools.cli import CliError

    try:
        headings = [float(word) for word in args.headings.split(',') if word.strip()]
        width, height = (int(word) for word in args.size.lower().split('x'))
    except ValueError:
        raise CliError(
            f'--headings must be numbers separated by commas and --size WxH, not '
            f'{args.headings!r} and {args.size!r}'
        ) from None
    if not headings or not all(np.isfinite(headings)):
        raise CliError(f'--headings must be finite numbers, not {args.headings!r}')
    if min(width, height) < 16:
        raise CliError(f'--size must be at least 16x16, not {args.size}')
    rig = dance_rig(args)
    if rig not in RIGS + ('both',):
        raise CliError(f'unknown rig {rig!r}; known: {", ".join(RIGS)}, both')
    if args.contours not in CONTOURS:
        raise CliError(f'unknown --contours {args.contours!r}; known: {", ".join(CONTOURS)}')
    if args.start not in STARTS:
        raise CliError(f'unknown --start {args.start!r}; known: {", ".join(STARTS)}')
    if args.shape not in SHAPES:
        raise CliError(f'unknown --shape {args.shape!r}; known: {", ".join(SHAPES)}')
    if args.tracker_body not in TRACKER_BODIES:
        raise CliError(
            f'unknown --tracker-body {args.tracker_body!r}; known: {", ".join(TRACKER_BODIES)}'
        )
    if args.body is not None:
        try:
            Body.from_yaml(args.body)
        except (OSError, ValueError, KeyError, TypeError) as error:
            raise CliError(f'--body {args.body}: {error}') from None
    if args.frames is not None and args.frames < 1:
        raise CliError('--frames must be at least 1')
    if args.jobs < 1:
        raise CliError('--jobs must be at least 1')
    rigs = list(RIGS) if rig == 'both' else [rig]
    return run_dance_benchmark(
        headings,
        rigs,
        args.frames,
        (width, height),
        args.contours,
        args.jobs,
        tracker_overrides(args.tracker),
        args.start,
        args.body,
        args.tracker_body,
        args.shape,
    )


def tracker_overrides(words: list[str]) -> dict:
    """Return {field: value} from NAME=VALUE words naming TrackerSettings numbers or flags."""
    from memo_ros.core.multiview.tracking import TrackerSettings
    from memo_ros.tools.cli import CliError

    defaults = TrackerSettings()
    out: dict = {}
    for word in words:
        name, _, text = word.partition('=')
        default = getattr(defaults, name, None)
        if isinstance(default, bool):
            if text.lower() not in ('true', 'false'):
                raise CliError(f'--tracker {word!r}: {text!r} is not true or false')
            out[name] = text.lower() == 'true'
            continue
        if not isinstance(default, (int, float)):
            raise CliError(
                f'--tracker {word!r}: not a numeric TrackerSettings field (nor a true/false one)'
            )
        try:
            value = type(default)(text)
        except ValueError:
            kind = type(default).__name__
            raise CliError(f'--tracker {word!r}: {text!r} is not a {kind}') from None
        if not np.isfinite(value) or value < 0:
            raise CliError(f'--tracker {word!r}: must be finite and not negative')
        out[name] = value
    return out


def run_dance_benchmark(
    headings_deg: list[float],
    rigs: list[str],
    frames: int | None = None,
    size: tuple[int, int] = SIZE,
    contours: str = 'images',
    jobs: int = 1,
    overrides: dict | None = None,
    start: str = 'given',
    body_file: str | None = None,
    tracker_body: str = 'truth',
    shape: str = SHAPES[0],
) -> dict:
    """Track studio-dance from every heading on every rig; return the runs and the worst figures.

    ``jobs`` runs go in parallel, each in its own process with one BLAS and one OpenCV thread.
    ``body_file``: the dancer's body YAML (default the shipped average); ``tracker_body``: see
    :data:`TRACKER_BODIES`; ``shape``: the dancer's as imaged (:data:`SHAPES`).
    """
    overrides = overrides or {}
    cases = [
        (rig, float(h), frames, size, contours, overrides, start, body_file, tracker_body, shape)
        for rig in rigs
        for h in headings_deg
    ]
    began = time.perf_counter()
    if jobs > 1 and len(cases) > 1:
        saved = {k: os.environ.get(k) for k in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS')}
        os.environ.update(dict.fromkeys(saved, '1'))  # the children start with one BLAS thread
        try:
            context = multiprocessing.get_context('spawn')
            with ProcessPoolExecutor(min(jobs, len(cases)), mp_context=context) as pool:
                runs = list(pool.map(_run_case, cases))
        finally:
            for key, value in saved.items():
                if value is None:
                    os.environ.pop(key, None)
                else:
                    os.environ[key] = value
    else:
        runs = [_run_case(case) for case in cases]
    return {
        'scenario': 'studio-dance',
        'size': list(size),
        'contours': contours,
        'noise': NOISE if contours == 'images' else 0.0,
        'jobs': jobs,
        'tracker': overrides,
        'start': start,
        'body': body_file or DEFAULT_BODY,
        'tracker_body': tracker_body,
        'shape': shape,
        'limits': {
            'mpjpe_mm_mean': MPJPE_MEAN_MM,
            'mpjpe_mm_max': MPJPE_MAX_MM,
            'heading_err_deg_max_after_1s': HEADING_MAX_DEG,
            'frames_side_swap': 0,
        },
        'runs': runs,
        'worst': _worst(runs),
        'seconds': time.perf_counter() - began,
    }


def _run_case(case: tuple) -> dict:
    """Run one case of :func:`run_dance_benchmark`; a pool's task."""
    import cv2

    cv2.setNumThreads(1)
    rig, heading, frames, size, contours, overrides, start, body_file, tracker_body, shape = case
    return track_dance(
        rig,
        heading,
        frames,
        size,
        contours,
        body=Body.from_yaml(body_file) if body_file else None,
        overrides=overrides,
        start=start,
        tracker_body=tracker_body,
        shape=shape,
    )


def track_dance(
    rig: str,
    heading_deg: float,
    frames: int | None = None,
    size: tuple[int, int] = SIZE,
    contours: str = 'images',
    body: Body | None = None,
    overrides: dict | None = None,
    start: str = 'given',
    tracker_body: str = 'truth',
    shape: str = SHAPES[0],
) -> dict:
    """Track one studio-dance offline and score it against its truth, frame by frame.

    ``body``: the dancer's; ``overrides``: TrackerSettings fields other than their defaults;
    ``start``: given (the true first pose) or silhouettes (no pose given); ``tracker_body``: truth
    (the dancer's body) or measured (:func:`measured_body`); ``shape``: the dancer's as imaged.
    """
    from memo_ros.core.multiview.proportions import (
        MEASURE_FRAMES,
        shoulder_width,
        upper_arm_length,
    )
    from memo_ros.core.multiview.tracking import TRACKING, ArticulatedTracker, TrackerSettings

    body = body or load_studio_actor()
    scenario = make_scenario(
        'studio-dance', body, *size, frames, heading=np.radians(heading_deg), rig=rig
    )
    times = np.arange(scenario.frames) / scenario.frame_rate
    q_true, _ = scenario.coordinates(times)
    true_r, true_o = body.forward_kinematics(q_true)
    settings = TrackerSettings(**(overrides or {}))
    initial = q_true[0] if start == 'given' else None
    est_r, est_o = np.full_like(true_r, np.nan), np.full_like(true_o, np.nan)
    tracked = np.zeros(len(times), bool)
    seconds = 0.0  # in the tracker's steps
    result = None
    measured_height = None
    tracker = None
    for k, tables in enumerate(_contour_frames(scenario, body, q_true, contours, shape)):
        if tracker is None:
            model = body
            tracking = settings
            if tracker_body == 'measured':
                model, measured_height = measured_body(scenario.cameras, tables, settings)
                # the shoulders, then the upper arms, each measured over a tracked second, as
                # tracker_node does it
                tracking = replace(
                    settings, proportion_frames=settings.proportion_frames or MEASURE_FRAMES
                )
            tracker = ArticulatedTracker(model, scenario.cameras, tracking, initial_pose=initial)
        started = time.perf_counter()
        result = tracker.step(int(round(times[k] * 1e9)), tables)
        seconds += time.perf_counter() - started
        if result.status == TRACKING and result.origins is not None:
            tracked[k] = True
            est_r[k], est_o[k] = result.rotations, result.origins
    joint_mm, _ = pose_errors(true_o, true_r, est_o, est_r)
    heading = np.abs(heading_error(true_r, est_r))
    swaps = side_swaps(true_o, est_o) & tracked[:, None]
    return _score(
        rig,
        heading_deg,
        times,
        tracked,
        joint_mm,
        heading,
        swaps,
        {
            'limb_exchanges': result.limb_exchanges if result else 0,
            'twin_swaps': result.twin_swaps if result else 0,
            'tracker_seconds': seconds,
            'body_height_m': body.standing_height(),
            'measured_height_m': measured_height,
            'measured_shoulders_m': (
                shoulder_width(tracker.body) if tracker and tracker.proportions else None
            ),
            'measured_upper_arms_m': (
                upper_arm_length(tracker.body) if tracker and tracker.proportions else None
            ),
        },
    )


def measured_body(
    cameras: list, tables: dict[str, np.ndarray], settings: TrackerSettings | None = None
) -> tuple[Body, float]:
    """Return the shipped average adult scaled to the height of one frame's silhouettes.

    As tracker_node measures a person with ``body_source: silhouettes`` (its ``body_frames``
    frames, one here; the visual hull's height, then the start's best fit from there up,
    ``body_height_fit``), and that height.
    """
    from memo_ros.core.multiview.body_height import fit_height

    template = load_default_body()
    _, hull = estimate_body([frame_silhouettes(cameras, tables)], template)
    height = fit_height(template, cameras, tables, hull, settings).height
    return scaled_body(template, height), height


def _contour_frames(
    scenario: Scenario, body: Body, q: np.ndarray, contours: str, shape: str = SHAPES[0]
) -> Iterator[dict[str, np.ndarray]]:
    """Yield every frame's contour tables per camera, as the contour nodes would publish them.

    ``images``: the studio's empty frames then the subject, rendered and imaged as the simulator
    does, through :class:`ContourPipeline` with the contour node's studio settings;
    ``silhouettes``: the exact outlines of the rendered body; ``shape``: the body's as imaged.
    """
    from memo_ros.core.simulation.imaging import ImagingOptions, background_image, simulated_frame
    from memo_ros.core.vision.contours import (
        ContourPipeline,
        occluding_contours,
        silhouette_outlines,
    )
    from memo_ros.nodes.contour_node import pipeline_settings
    from memo_ros.tools.launch import REPLAY_WINDOW_MARGIN

    cameras = scenario.cameras
    if contours == 'silhouettes':
        for k in range(len(q)):
            rotations, origins = body.forward_kinematics(q[k])
            yield {
                c.name: occluding_contours(
                    silhouette_outlines(
                        render(
                            c, rotations, origins, body.semi_axes, body.lengths, shape=shape
                        ).label
                        > 0
                    )
                )
                for c in cameras
            }
        return
    options = ImagingOptions(noise=NOISE)
    rng = np.random.default_rng(options.seed)
    backgrounds = {c.name: background_image(c, options.seed) for c in cameras}
    # segmented as a replay segments them (memo-ros launch --reliable-images): whole frames
    params = {**scenario.contour_parameters, 'window_margin': REPLAY_WINDOW_MARGIN}
    pipelines = {c.name: ContourPipeline(pipeline_settings(params)) for c in cameras}
    for k in range(scenario.empty_frames + len(q)):
        b = k - scenario.empty_frames  # the subject's frame; negative while the studio is empty
        rotations, origins = body.forward_kinematics(q[max(b, 0)])
        tables = {}
        for c in cameras:
            pixels = simulated_frame(
                c,
                body,
                rotations,
                origins,
                backgrounds[c.name],
                options,
                k,
                rng,
                empty=b < 0,
                shape=shape,
            )
            tables[c.name] = pipelines[c.name].process(pixels, edges=False).contours
        if b >= 0:
            yield tables


def _score(
    rig: str,
    heading_deg: float,
    times: np.ndarray,
    tracked: np.ndarray,
    joint_mm: np.ndarray,
    heading: np.ndarray,
    swaps: np.ndarray,
    extra: dict,
) -> dict:
    """Return one run's figures, its verdict and, where it fails, when, during what, and where."""
    mpjpe = joint_mm.mean(axis=1)  # NaN where untracked
    settled = (times >= SETTLE_S) & tracked
    run = {
        'rig': rig,
        'heading_deg': heading_deg,
        'frames': int(len(times)),
        'untracked': int((~tracked).sum()),
        'mpjpe_mm_mean': float(np.mean(mpjpe[tracked])) if tracked.any() else None,
        'mpjpe_mm_max': float(np.max(mpjpe[tracked])) if tracked.any() else None,
        'heading_err_deg_max_after_1s': float(heading[settled].max()) if settled.any() else None,
        'frames_side_swap': int(swaps.any(axis=1).sum()),
        **{
            f'frames_side_swap_{pair}': int(swaps[:, k].sum()) for k, pair in enumerate(SWAP_PAIRS)
        },
        **extra,
    }
    failing = {
        'untracked': ~tracked,
        f'MPJPE > {MPJPE_MAX_MM:g} mm': tracked & (np.nan_to_num(mpjpe) > MPJPE_MAX_MM),
        f'heading error >= {HEADING_MAX_DEG:g} deg': settled
        & (np.nan_to_num(heading) >= HEADING_MAX_DEG),
        'side swap': swaps.any(axis=1),
    }
    run['passed'] = bool(
        not any(mask.any() for mask in failing.values())
        and run['mpjpe_mm_mean'] is not None
        and run['mpjpe_mm_mean'] <= MPJPE_MEAN_MM
    )
    run['failures'] = [
        _window(what, times, mask, joint_mm, swaps)
        for what, mask in failing.items()
        for mask in _runs_of(mask)
    ]
    return run


def _runs_of(mask: np.ndarray) -> list[np.ndarray]:
    """Split a boolean frame mask into one mask per run of consecutive true frames."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(int), [0]])))
    out = []
    for first, stop in zip(edges[::2], edges[1::2]):
        one = np.zeros_like(mask)
        one[first:stop] = True
        out.append(one)
    return out


def _window(
    what: str, times: np.ndarray, mask: np.ndarray, joint_mm: np.ndarray, swaps: np.ndarray
) -> dict:
    """Describe one failing window: its times, the moves under way, the worst parts, swaps."""
    start, end = float(times[mask][0]), float(times[mask][-1])
    part_mm = np.nanmean(joint_mm[mask], axis=0) if np.isfinite(joint_mm[mask]).any() else None
    worst = [] if part_mm is None else [int(i) for i in np.argsort(-np.nan_to_num(part_mm))[:3]]
    return {
        'what': what,
        'start_s': start,
        'end_s': end,
        'moves': dance_moves(start, end),
        'parts': {PART_NAMES[i]: float(part_mm[i]) for i in worst} if part_mm is not None else {},
        'swapped': [pair for k, pair in enumerate(SWAP_PAIRS) if swaps[mask, k].any()],
    }


def _worst(runs: list[dict]) -> dict:
    """Return the worst figure of every kind over all runs, with the run it came from."""
    out: dict = {'runs': len(runs), 'passed': sum(r['passed'] for r in runs)}
    for key in (
        'mpjpe_mm_mean',
        'mpjpe_mm_max',
        'heading_err_deg_max_after_1s',
        'frames_side_swap',
        'untracked',
        'limb_exchanges',
    ):
        have = [r for r in runs if r[key] is not None]
        if have:
            run = max(have, key=lambda r, key=key: r[key])
            out[key] = {'value': run[key], 'rig': run['rig'], 'heading_deg': run['heading_deg']}
    return out


def _span_mm(runs: list[dict], key: str) -> str:
    """Return the runs' least and largest ``key`` (m) as 'a - b mm', or 'no run'."""
    values = [r[key] for r in runs if r.get(key)]
    return f'{1e3 * min(values):.0f} - {1e3 * max(values):.0f} mm' if values else 'no run'


def print_dance_benchmark(report: dict) -> None:
    """One row per run, the worst figures, and where the failing runs failed."""
    w, h = report['size']
    source = (
        f'the contour pipeline (contour_node, studio settings) on simulated {w}x{h} images, '
        f'sensor noise {report["noise"]:g} grey levels'
        if report['contours'] == 'images'
        else f'exact rendered {w}x{h} silhouettes'
    )
    limits = report['limits']
    settings = ', '.join(f'{k}={v}' for k, v in report.get('tracker', {}).items())
    started = (
        'started at the true first pose'
        if report.get('start', 'given') == 'given'
        else 'started from the silhouettes (no pose given)'
    )
    print(
        f'studio-dance tracked offline by ArticulatedTracker(TrackerSettings({settings})), '
        f'{started}, every camera for every part; contours: {source}'
    )
    runs = report['runs']
    dancer = f'dancer: {report.get("body", DEFAULT_BODY)}'
    if runs:
        dancer += f' ({runs[0].get("body_height_m", float("nan")):.3f} m)'
    if report.get('shape', SHAPES[0]) != SHAPES[0]:
        dancer += f', imaged as {report["shape"]} parts'
    if report.get('tracker_body', 'truth') == 'measured':
        heights = [r['measured_height_m'] for r in runs if r.get('measured_height_m')]
        span = f'{min(heights):.3f} - {max(heights):.3f} m' if heights else 'no run'
        apart = _span_mm(runs, 'measured_shoulders_m')
        long = _span_mm(runs, 'measured_upper_arms_m')
        print(
            f"{dancer}; the tracker's body: the shipped average scaled to the height measured "
            f"from the first frame's silhouettes ({span}), its shoulder joints ({apart} apart) "
            f'then its upper arms ({long} long) each measured over a tracked second'
        )
    else:
        print(f"{dancer}; the tracker is given the dancer's body")
    print(
        f'Done-when: MPJPE mean <= {limits["mpjpe_mm_mean"]:g} mm, no frame over '
        f'{limits["mpjpe_mm_max"]:g} mm, heading error < '
        f'{limits["heading_err_deg_max_after_1s"]:g} deg from {SETTLE_S:g} s on, no side swap, '
        'every frame tracked'
    )
    print(
        f'{"rig":<10} {"heading":>7} {"frames":>6} {"untracked":>9} {"MPJPE mean":>10} '
        f'{"MPJPE max":>9} {"heading>1s":>10} {"swaps":>5} {"arms/legs":>9} {"limb exch":>9} '
        f'{"twin":>4} {"ms/step":>7}  result'
    )
    for r in report['runs']:
        print(
            f'{r["rig"]:<10} {r["heading_deg"]:>7g} {r["frames"]:>6} {r["untracked"]:>9} '
            f'{_number(r["mpjpe_mm_mean"]):>10} {_number(r["mpjpe_mm_max"]):>9} '
            f'{_number(r["heading_err_deg_max_after_1s"]):>10} {r["frames_side_swap"]:>5} '
            f'{r["frames_side_swap_arms"]:>4}/{r["frames_side_swap_legs"]:<4} '
            f'{r["limb_exchanges"]:>9} {r["twin_swaps"]:>4} '
            f'{1000 * r["tracker_seconds"] / max(r["frames"], 1):>7.0f}  '
            f'{"pass" if r["passed"] else "FAIL"}'
        )
    worst = report['worst']
    parts = []
    for key, label, unit in (
        ('mpjpe_mm_mean', 'MPJPE mean', ' mm'),
        ('mpjpe_mm_max', 'MPJPE max', ' mm'),
        ('heading_err_deg_max_after_1s', 'heading error after 1 s', ' deg'),
        ('frames_side_swap', 'side-swap frames', ''),
        ('untracked', 'untracked frames', ''),
    ):
        if key in worst:
            v = worst[key]
            parts.append(
                f'{label} {_number(v["value"])}{unit} ({v["rig"]} {v["heading_deg"]:g} deg)'
            )
    print(f'worst: {"; ".join(parts)}; {worst["passed"]} of {worst["runs"]} runs pass')
    failing = [r for r in report['runs'] if r['failures']]
    if failing:
        print('where the failing runs fail (time window: the dance moves under way; worst parts):')
    for r in failing:
        for f in r['failures'][:4]:
            parts_text = ', '.join(f'{p} {mm:.0f} mm' for p, mm in f['parts'].items())
            swapped = f'; swapped: {"/".join(f["swapped"])}' if f['swapped'] else ''
            print(
                f'  {r["rig"]} {r["heading_deg"]:g} deg: {f["what"]} at {f["start_s"]:.2f}-'
                f'{f["end_s"]:.2f} s ({", ".join(f["moves"]) or "standing"}): {parts_text}'
                f'{swapped}'
            )
        if len(r['failures']) > 4:
            print(f'  {r["rig"]} {r["heading_deg"]:g} deg: {len(r["failures"]) - 4} more windows')
    print(
        f'time: {report["seconds"]:.0f} s for {len(report["runs"])} runs, {report["jobs"]} in '
        'parallel'
    )


def _number(value: float | None) -> str:
    """Return a count as it is, a measure with one decimal, or n/a."""
    if value is None:
        return 'n/a'
    return str(value) if isinstance(value, int) else f'{value:.1f}'


def _cpus() -> int:
    """Return the CPUs this process may use."""
    if hasattr(os, 'sched_getaffinity'):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1
