"""Render a simulated scenario into a rosbag2 with ground truth and a studio YAML beside it.

Per camera ``/<cam>/image_raw`` and ``/<cam>/camera_info``; the truth on
``/memo/truth/joint_states`` and ``/memo/truth/body_poses`` with the tracker's
types and conventions.  The studio file ``OUT.yaml`` starts the graph.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
import math
from pathlib import Path
import shutil
import sys
import time

import numpy as np

from memo_ros.core.formats.studio import Studio
from memo_ros.core.geometry.body import Body, load_studio_actor
from memo_ros.core.geometry.render import SHAPES
from memo_ros.core.geometry.rotations import matrix_to_quat
from memo_ros.core.simulation.imaging import (
    ImagingOptions,
    background_image,
    simulated_frame,
)
from memo_ros.core.simulation.scenarios import RIGS, SCENARIOS, Scenario, make_scenario
from memo_ros.ros.bagio import (
    BagWriter,
    camera_info_msg,
    image_msg,
    joint_state_msg,
    pose_array_msg,
)
from memo_ros.tools.progress import Progress

START_NS = 1_767_225_600 * 1_000_000_000  # 2026-01-01T00:00:00Z: fixed, so runs are reproducible
ENCODINGS = ('mono8', 'mono16', 'rgb8', 'bgr8', 'rgba8', 'bgra8')
TRUTH_JOINTS = '/memo/truth/joint_states'
TRUTH_POSES = '/memo/truth/body_poses'


@dataclass
class SimulationResult:
    """What a simulation wrote."""

    bag: Path
    studio: Path
    frames: int
    cameras: list[str]
    seconds: float
    empty_frames: int = (
        0  # frames of the empty scene before the subject, not counted in ``frames``
    )


def finite_positive(text: str) -> float:
    """Parse an argparse number that must be finite and > 0."""
    value = float(text)
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f'must be a finite number > 0, not {text}')
    return value


def finite_non_negative(text: str) -> float:
    """Parse an argparse number that must be finite and >= 0."""
    value = float(text)
    if not math.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f'must be a finite number >= 0, not {text}')
    return value


def finite(text: str) -> float:
    """Parse an argparse number that must be finite."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f'must be a finite number, not {text}')
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare this command's arguments and options."""
    parser.add_argument('scenario', help=f'one of: {", ".join(SCENARIOS)}')
    parser.add_argument(
        '--out',
        '-o',
        type=Path,
        help='output bag directory (default out/<scenario>); '
        'the studio YAML is written beside it as OUT.yaml',
    )
    parser.add_argument('--frames', type=int, help='number of frames (default per scenario)')
    parser.add_argument(
        '--rate', type=finite_positive, help='frames per second (default per scenario)'
    )
    parser.add_argument('--width', type=int, default=640)
    parser.add_argument('--height', type=int, default=480)
    parser.add_argument(
        '--noise',
        type=finite_non_negative,
        default=3.0,
        help='sensor noise sigma in grey levels (0 = none)',
    )
    parser.add_argument(
        '--blur', type=finite_non_negative, default=0.0, help='optical blur sigma in pixels'
    )
    parser.add_argument(
        '--lighting-change',
        type=float,
        default=0.0,
        help='amplitude of a slow global lighting change (0.1 = +-10%%)',
    )
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument(
        '--no-initial-pose',
        action='store_true',
        help="leave the subject's true starting pose out of the studio file, so the tracker "
        'initialises itself from the silhouettes',
    )
    parser.add_argument(
        '--empty-frames',
        type=int,
        help='frames of the empty scene before the subject appears '
        '(default: 10 in the studio, 0 in the street)',
    )
    parser.add_argument(
        '--encoding', default='mono8', help=f'image encoding: {", ".join(ENCODINGS)}'
    )
    parser.add_argument('--storage', default='mcap', choices=('mcap', 'sqlite3'))
    parser.add_argument(
        '--body',
        type=Path,
        help="body YAML (default: the simulated studios' actor, config/body_studio_actor.yaml)",
    )
    parser.add_argument(
        '--heading',
        type=finite,
        metavar='DEG',
        help='studio-dance: the heading the subject starts facing, degrees from the world x axis '
        'towards y (default: random from --seed, printed)',
    )
    parser.add_argument(
        '--rig',
        help=f'studio scenarios: the cameras, one of {", ".join(RIGS)} (default orthogonal: '
        'front, side, overhead; ring4: four cameras on an uneven ring)',
    )
    parser.add_argument(
        '--shape',
        default=SHAPES[0],
        help=f"the body's shape as imaged: {' or '.join(SHAPES)} (elliptic capsules merging "
        "over the joints: a person the tracker's cylinders fit less exactly); default "
        f'{SHAPES[0]}',
    )
    parser.add_argument('--force', action='store_true', help='replace an existing output')
    parser.add_argument(
        '--progress', action='store_true', help='show progress even when not on a terminal'
    )


def run(args: argparse.Namespace) -> int:
    """Run the command with parsed ``args``; return its exit code."""
    from memo_ros.tools.cli import CliError

    if args.scenario not in SCENARIOS:
        raise CliError(f'unknown scenario {args.scenario!r}; known: {", ".join(SCENARIOS)}')
    if args.encoding not in ENCODINGS:
        raise CliError(f'unknown encoding {args.encoding!r}; known: {", ".join(ENCODINGS)}')
    for name in ('frames', 'width', 'height'):
        value = getattr(args, name)
        if value is not None and value <= 0:
            raise CliError(f'--{name} must be positive')
    if args.rate is not None and args.rate <= 0:
        raise CliError('--rate must be positive')
    if min(args.noise, args.blur, args.lighting_change) < 0:
        raise CliError('--noise, --blur and --lighting-change must not be negative')
    if args.rig is not None and args.rig not in RIGS:
        raise CliError(f'unknown rig {args.rig!r}; known: {", ".join(RIGS)}')
    if args.rig is not None and not args.scenario.startswith('studio-'):
        raise CliError(f'--rig is for the studio scenarios; {args.scenario} has its own camera')
    if args.shape not in SHAPES:
        raise CliError(f'unknown shape {args.shape!r}; known: {", ".join(SHAPES)}')
    if args.heading is not None and args.scenario != 'studio-dance':
        raise CliError(f'--heading is for studio-dance; {args.scenario} takes none')
    heading_deg, chosen = args.heading, 'given'
    if args.scenario == 'studio-dance' and heading_deg is None:
        heading_deg = float(np.random.default_rng(args.seed).uniform(0.0, 360.0))
        chosen = f'random from --seed {args.seed}'
    body = Body.from_yaml(args.body) if args.body else load_studio_actor()
    out = args.out or Path('out') / args.scenario
    result = simulate(
        args.scenario,
        out,
        body=body,
        frames=args.frames,
        frame_rate=args.rate,
        width=args.width,
        height=args.height,
        options=ImagingOptions(args.noise, args.blur, args.lighting_change, args.seed),
        encoding=args.encoding,
        storage=args.storage,
        force=args.force,
        progress=args.progress or sys.stderr.isatty(),
        empty_frames=args.empty_frames,
        initial_pose=not args.no_initial_pose,
        heading=None if heading_deg is None else math.radians(heading_deg),
        rig=args.rig,
        shape=args.shape,
    )
    print(f'scenario   {args.scenario}')
    if heading_deg is not None:
        print(f'heading    {heading_deg:.1f} deg ({chosen})')
    if args.scenario.startswith('studio-'):
        print(f'rig        {args.rig or "orthogonal"}')
    total = result.frames + result.empty_frames
    print(
        f'bag        {result.bag}  ({result.empty_frames} empty + {result.frames} frames '
        f'x {len(result.cameras)} cameras: '
        f'{", ".join(result.cameras)})'
    )
    print(f'studio     {result.studio}')
    print(
        'topics     '
        + ', '.join(
            [f'/{c}/image_raw, /{c}/camera_info' for c in result.cameras]
            + [TRUTH_JOINTS, TRUTH_POSES]
        )
    )
    print(f'time       {result.seconds:.1f} s ({total / max(result.seconds, 1e-9):.1f} frames/s)')
    return 0


def simulate(
    scenario_name: str,
    out: Path,
    body: Body | None = None,
    frames: int | None = None,
    frame_rate: float | None = None,
    width: int = 640,
    height: int = 480,
    options: ImagingOptions | None = None,
    encoding: str = 'mono8',
    storage: str = 'mcap',
    force: bool = False,
    progress: bool = False,
    drop: dict[str, int] | None = None,
    empty_frames: int | None = None,
    initial_pose: bool = True,
    heading: float | None = None,
    rig: str | None = None,
    shape: str = SHAPES[0],
) -> SimulationResult:
    """Simulate ``scenario_name`` into the bag ``out`` and the studio ``out.yaml``.

    ``drop`` maps a camera name to the frame index (counting empty frames) from which
    it stops publishing (a camera lost mid-run); ``empty_frames`` overrides the
    scenario's number of empty-scene frames before the subject appears; ``heading``
    (rad) and ``rig`` go to :func:`make_scenario` (studio-dance's start, a studio's cameras);
    ``shape`` is how the body is imaged (:data:`SHAPES`).
    """
    body = body or load_studio_actor()
    options = options or ImagingOptions()
    scenario = make_scenario(
        scenario_name, body, width, height, frames, frame_rate, heading=heading, rig=rig
    )
    if empty_frames is not None:
        if empty_frames < 0:
            raise ValueError('empty_frames must not be negative')
        scenario.empty_frames = empty_frames
        if 'background_frames' in scenario.contour_parameters and empty_frames:
            scenario.contour_parameters['background_frames'] = empty_frames
    out = Path(out)
    studio_path = out.with_name(out.name + '.yaml')
    if out.exists():
        if not force:
            raise FileExistsError(f'{out} exists already (use --force to replace it)')
        shutil.rmtree(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    # Kakadiaris & Metaxas assume the initial pose known: the studio carries the subject's first
    # true pose
    q0, _ = scenario.coordinates(np.zeros(1))
    start_pose = dict(zip(body.coordinate_names, map(float, q0[0]))) if initial_pose else {}
    Studio(
        scenario_name.replace('-', '_'),
        scenario.cameras,
        body,
        scenario.frame_rate,
        {'contour_node': scenario.contour_parameters, **scenario.node_parameters},
        start_pose,
    ).save(studio_path)
    start = time.perf_counter()
    _write_bag(scenario, body, out, options, encoding, storage, progress, drop or {}, shape)
    return SimulationResult(
        out,
        studio_path,
        scenario.frames,
        [c.name for c in scenario.cameras],
        time.perf_counter() - start,
        scenario.empty_frames,
    )


def _write_bag(
    scenario: Scenario,
    body: Body,
    out: Path,
    options: ImagingOptions,
    encoding: str,
    storage: str,
    progress: bool,
    drop: dict[str, int],
    shape: str = SHAPES[0],
) -> None:
    rng = np.random.default_rng(options.seed)
    times = np.arange(scenario.frames) / scenario.frame_rate
    q_all, phase_all = scenario.coordinates(times)
    qd_all = scenario.velocities(times)
    backgrounds = {c.name: background_image(c, options.seed) for c in scenario.cameras}
    infos = {c.name: c.to_camera_info_fields() for c in scenario.cameras}
    names = list(body.coordinate_names)
    if phase_all is not None:
        names.append('gait_phase')
    total = scenario.empty_frames + scenario.frames
    bar = Progress(total, 'simulate', enabled=progress)
    with BagWriter(out, storage) as writer:
        for k in range(total):
            stamp = START_NS + int(round(k / scenario.frame_rate * 1e9))
            b = k - scenario.empty_frames  # body frame index; negative while the scene is empty
            rotations, origins = body.forward_kinematics(q_all[max(b, 0)])
            for cam in scenario.cameras:
                if k >= drop.get(cam.name, total + 1):
                    continue
                pixels = simulated_frame(
                    cam,
                    body,
                    rotations,
                    origins,
                    backgrounds[cam.name],
                    options,
                    k,
                    rng,
                    empty=b < 0,
                    colour=encoding not in ('mono8', 'mono16'),
                    shape=shape,
                )
                # camera_info first, as a driver's calibration precedes the pixels that need it
                writer.write(
                    f'/{cam.name}/camera_info', stamp, camera_info_msg(stamp, infos[cam.name])
                )
                writer.write(
                    f'/{cam.name}/image_raw',
                    stamp,
                    image_msg(
                        stamp, infos[cam.name]['frame_id'], *convert_encoding(pixels, encoding)
                    ),
                )
            if b >= 0:
                positions, velocities = list(q_all[b]), list(qd_all[b])
                if phase_all is not None:
                    positions.append(float(phase_all[b]))
                    velocities.append(_phase_rate(phase_all, b, scenario.frame_rate))
                writer.write(
                    TRUTH_JOINTS, stamp, joint_state_msg(stamp, names, positions, velocities)
                )
                writer.write(
                    TRUTH_POSES, stamp, pose_array_msg(stamp, origins, matrix_to_quat(rotations))
                )
            bar.update(k + 1)
    bar.close()


def _phase_rate(phase: np.ndarray, k: int, rate: float) -> float:
    """Gait phase velocity (cycles/s) from neighbouring frames, unwrapped."""
    if len(phase) < 2:
        return 0.0
    j = min(k + 1, len(phase) - 1)
    i = j - 1
    return float(np.mod(phase[j] - phase[i], 1.0) * rate)


def convert_encoding(pixels: np.ndarray, encoding: str) -> tuple[np.ndarray, str]:
    """Convert a uint8 grey (H, W) or BGR (H, W, 3) picture to ``encoding``."""
    if pixels.ndim == 2:
        grey = pixels
        bgr = np.repeat(pixels[..., None], 3, axis=2)
    else:
        bgr = pixels
        grey = (bgr @ np.array([0.114, 0.587, 0.299])).round().clip(0, 255).astype(np.uint8)
    if encoding == 'mono8':
        return grey, encoding
    if encoding == 'mono16':
        return grey.astype(np.uint16) * 257, encoding
    if encoding == 'bgr8':
        return bgr, encoding
    if encoding == 'rgb8':
        return bgr[..., ::-1], encoding
    alpha = np.full(bgr.shape[:2] + (1,), 255, np.uint8)
    if encoding == 'bgra8':
        return np.concatenate([bgr, alpha], axis=2), encoding
    if encoding == 'rgba8':
        return np.concatenate([bgr[..., ::-1], alpha], axis=2), encoding
    raise ValueError(f'unknown encoding {encoding!r}')
