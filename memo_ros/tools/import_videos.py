"""Import recorded videos and their calibration into a rosbag2, with a studio YAML beside it.

``memo-ros import videos CAM1.mp4 CAM2.mp4 ... --calibration FILE --out BAG``
(or ``memo-ros import videos FOLDER --out BAG``: a recording folder's videos and
its one calibration, flat or in a Pose2Sim project's ``videos/`` and
``calibration/``) decodes the videos with OpenCV, one frame per camera in memory at a time, and
writes ``/<cam>/image_raw`` and ``/<cam>/camera_info`` per camera, stamped
``first + (k / fps + offset)`` for frame k, in time order; ``BAG.yaml`` is the
studio (every camera's intrinsics and pose, the body, the frame rate), as
``memo-ros simulate`` writes it.  Videos map to calibration cameras by
``--names``, else by file stem when every stem names a camera, else by order.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
import heapq
import os
from pathlib import Path
import shutil
import sys
import time
from typing import Iterator

import numpy as np

from memo_ros.core.formats.calibration import (
    READ_FORMATS,
    UNITS,
    Calibration,
    CalibrationError,
    load_calibration,
    natural_key,
    ros_name,
)
from memo_ros.core.formats.studio import Studio
from memo_ros.core.geometry.body import Body, load_default_body
from memo_ros.core.geometry.camera import Camera
from memo_ros.ros.bagio import BagWriter, camera_info_msg, image_msg
from memo_ros.tools.progress import Progress
from memo_ros.tools.simulate import START_NS

ENCODINGS = ('mono8', 'bgr8', 'rgb8')
CROP_TOLERANCE = 16  # px: one H.264 macroblock; codecs pad or crop frames to a multiple of it


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare this command's arguments and options."""
    parser.add_argument('kind', choices=('videos',), help='what to import: videos')
    parser.add_argument(
        'videos',
        nargs='+',
        type=Path,
        help='one video per camera, or a recording folder: its videos (*.mp4, *.avi, *.mov, '
        '*.mkv) and, without --calibration, its one Calib*.toml or *.qca.txt, each flat or in '
        "a Pose2Sim project's videos/ and calibration/",
    )
    parser.add_argument(
        '--calibration',
        '-c',
        type=Path,
        help='Qualisys .qca.txt, calibration.toml, EasyMocap folder (intri.yml + extri.yml), '
        'ROS calibration folder (<cam>.yaml + poses.yaml) or a memo_ros studio YAML '
        '(required with video files; found in a recording folder)',
    )
    parser.add_argument('--calibration-format', choices=READ_FORMATS, help='skip format detection')
    parser.add_argument(
        '--calibration-unit',
        choices=tuple(UNITS),
        default='m',
        help='length unit of toml / EasyMocap translations (default m, as Pose2Sim and EasyMocap; '
        'Anipose and FreeMoCap use their board unit, often mm)',
    )
    parser.add_argument(
        '--poses', type=Path, help='ROS calibration: the poses YAML (default poses.yaml beside)'
    )
    parser.add_argument(
        '--out',
        '-o',
        type=Path,
        required=True,
        help='output bag directory; the studio YAML is written beside it as OUT.yaml',
    )
    parser.add_argument(
        '--names', help='comma-separated calibration camera names of the videos, in order'
    )
    parser.add_argument(
        '--rename', action='store_true', help="name each camera after its video's file stem"
    )
    parser.add_argument('--fps', type=float, help="frame rate (default: the videos' own)")
    parser.add_argument(
        '--offset',
        action='append',
        default=[],
        metavar='CAM=SECONDS',
        help="time of CAM's first frame after the others' (unsynchronised rigs; repeatable)",
    )
    parser.add_argument(
        '--frames',
        metavar='FIRST:LAST[:STEP]',
        help='frame range FIRST <= k < LAST (either may be empty), every STEP-th frame (default '
        "1); stamps keep the video's clock, so a step makes the motion between frames faster",
    )
    parser.add_argument(
        '--scale', type=float, default=1.0, help='resize the images by this factor (e.g. 0.25)'
    )
    parser.add_argument('--encoding', choices=ENCODINGS, default='mono8')
    parser.add_argument(
        '--crop-tolerance',
        type=int,
        default=CROP_TOLERANCE,
        metavar='PX',
        help='accept a video up to PX pixels narrower / shorter than calibrated as cropped at the '
        f'right / bottom (codec alignment; default {CROP_TOLERANCE}, 0 = exact sizes only)',
    )
    parser.add_argument(
        '--body', type=Path, help='body YAML for the studio (default: the shipped average adult)'
    )
    parser.add_argument('--storage', default='mcap', choices=('mcap', 'sqlite3'))
    parser.add_argument('--force', action='store_true', help='replace an existing output')
    parser.add_argument(
        '--progress', action='store_true', help='show progress even when not on a terminal'
    )


@dataclass
class VideoSource:
    """One opened video and the camera it feeds."""

    path: Path
    camera: Camera  # calibrated at the video's size, before --scale
    capture: object  # cv2.VideoCapture
    width: int
    height: int
    fps: float
    frame_count: int  # as the container claims (may be approximate)
    offset: float = 0.0


@dataclass
class ImportResult:
    """What an import wrote."""

    bag: Path
    studio: Path
    frames: dict[str, int]
    cameras: list[Camera]
    frame_rate: float
    seconds: float
    notes: list[str]


def run(args: argparse.Namespace) -> int:
    """Run the command with parsed ``args``; return its exit code."""
    from memo_ros.tools.cli import CliError

    videos, calibration = args.videos, args.calibration
    try:
        if len(videos) == 1 and videos[0].is_dir():
            videos, calibration = recording_folder(videos[0], calibration)
        if calibration is None:
            raise VideoImportError('--calibration is needed with video files (or give a folder)')
        result = import_videos(
            videos,
            calibration,
            args.out,
            fmt=args.calibration_format,
            unit=args.calibration_unit,
            poses=args.poses,
            names=_split_names(args.names),
            rename=args.rename,
            fps=args.fps,
            offsets=parse_offsets(args.offset),
            frames=parse_frames(args.frames),
            scale=args.scale,
            encoding=args.encoding,
            crop_tolerance=args.crop_tolerance,
            body=Body.from_yaml(args.body) if args.body else None,
            storage=args.storage,
            force=args.force,
            progress=args.progress or sys.stderr.isatty(),
        )
    except (CalibrationError, VideoImportError, FileExistsError) as exc:
        raise CliError(str(exc)) from None
    for note in result.notes:
        print(f'memo-ros import: warning: {note}', file=sys.stderr)
    total = sum(result.frames.values())
    print(
        f'bag        {result.bag}  ({total} images from {len(result.cameras)} cameras: '
        + ', '.join(f'{name} {n}' for name, n in result.frames.items())
        + ')'
    )
    print(f'studio     {result.studio}  ({result.frame_rate:g} frames/s)')
    for cam in result.cameras:
        print(
            f'camera     {cam.name}: {cam.width}x{cam.height}, fx {cam.K[0, 0]:.1f}, '
            f'{cam.distortion_model}, '
            f'{np.linalg.norm(cam.t_world_cam):.2f} m from the origin'
        )
    print(f'time       {result.seconds:.1f} s ({total / max(result.seconds, 1e-9):.1f} images/s)')
    return 0


class VideoImportError(ValueError):
    """Videos that cannot be imported as asked (a user error, reported in one line)."""


VIDEO_SUFFIXES = ('.mp4', '.avi', '.mov', '.mkv')
CALIBRATION_PATTERNS = ('Calib*.toml', 'calib*.toml', '*.qca.txt')


def recording_folder(folder: Path, calibration: Path | None = None) -> tuple[list[Path], Path]:
    """Return a recording folder's videos (natural order) and its calibration.

    Flat, as ../shared holds the Pose2Sim demo, or a Pose2Sim project's ``videos/`` and
    ``calibration/``; ``calibration`` given wins over the folder's.
    """
    places = (folder, folder / 'videos')
    videos = sorted(
        {p for place in places for p in place.glob('*') if p.suffix.lower() in VIDEO_SUFFIXES},
        key=lambda p: natural_key(p.name),
    )
    if len(videos) < 2:
        raise VideoImportError(
            f'{folder}: {len(videos)} videos ({", ".join(VIDEO_SUFFIXES)}, there or in videos/); '
            'a rig needs at least 2'
        )
    if calibration is not None:
        return videos, calibration
    found = sorted(
        {
            p
            for place in (folder, folder / 'calibration')
            for pattern in CALIBRATION_PATTERNS
            for p in place.glob(pattern)
        }
    )
    if len(found) != 1:
        raise VideoImportError(
            f'{folder}: {len(found)} calibrations (Calib*.toml or *.qca.txt, there or in '
            f'calibration/){": " + ", ".join(p.name for p in found) if found else ""}; give '
            'the one to use with --calibration'
        )
    return videos, found[0]


def _split_names(text: str | None) -> list[str] | None:
    return [n.strip() for n in text.split(',')] if text else None


def parse_frames(text: str | None) -> tuple[int, int | None, int]:
    """(first, last, step) of 'FIRST:LAST[:STEP]'.

    Half-open; empty FIRST or LAST mean the start / the end, an empty STEP 1.
    """
    if not text:
        return 0, None, 1
    parts = text.split(':')
    try:
        if len(parts) not in (2, 3):
            raise ValueError
        first = int(parts[0]) if parts[0].strip() else 0
        last = int(parts[1]) if parts[1].strip() else None
        step = int(parts[2]) if len(parts) == 3 and parts[2].strip() else 1
    except ValueError:
        raise VideoImportError(
            f'--frames {text!r}: expected FIRST:LAST or FIRST:LAST:STEP, e.g. 0:100 or 0:100:2'
        ) from None
    if first < 0 or (last is not None and last <= first):
        raise VideoImportError(f'--frames {text!r}: need 0 <= FIRST < LAST')
    if step < 1:
        raise VideoImportError(f'--frames {text!r}: STEP must be at least 1')
    return first, last, step


def parse_offsets(items: list[str]) -> dict[str, float]:
    """{camera: seconds} of repeated 'CAM=SECONDS' options."""
    offsets = {}
    for item in items:
        name, sep, value = item.partition('=')
        try:
            if not sep or not name.strip():
                raise ValueError
            offsets[name.strip()] = float(value)
        except ValueError:
            raise VideoImportError(
                f'--offset {item!r}: expected CAM=SECONDS, e.g. cam02=0.033'
            ) from None
    return offsets


def match_videos(
    videos: list[Path], cameras: list[Camera], names: list[str] | None = None
) -> list[Camera]:
    """Return the calibration camera of each video.

    By ``names``, else by file stem if all stems match, else by order.
    """
    by_name = {c.name: c for c in cameras}
    if names is not None:
        if len(names) != len(videos):
            raise VideoImportError(f'--names lists {len(names)} cameras for {len(videos)} videos')
        unknown = [n for n in names if n not in by_name]
        if unknown:
            raise VideoImportError(
                f'--names: no camera {", ".join(unknown)} in the calibration '
                f'(it has {", ".join(by_name)})'
            )
        chosen = [by_name[n] for n in names]
    else:
        folded = {c.name.lower(): c for c in cameras}
        stems = [ros_name(v.name.split('.')[0], i).lower() for i, v in enumerate(videos)]
        if all(s in folded for s in stems):
            chosen = [folded[s] for s in stems]
        elif len(videos) != len(cameras):
            raise VideoImportError(
                f'{len(videos)} videos but {len(cameras)} calibrated cameras '
                f'({", ".join(by_name)}): name the videos after the cameras or pass --names'
            )
        else:
            chosen = list(cameras)
    repeated = sorted({c.name for c in chosen if chosen.count(c) > 1})
    if repeated:
        raise VideoImportError(f'camera {", ".join(repeated)} given more than one video')
    return chosen


def fit_camera(
    cam: Camera, width: int, height: int, size_known: bool, crop_tolerance: int, video: Path
) -> tuple[Camera, str | None]:
    """Return the camera at the video's frame size, and a note when that needed an assumption.

    Else a one-line error.
    """
    if (cam.width, cam.height) == (width, height):
        return cam, None
    resized = Camera(
        cam.name,
        width,
        height,
        cam.K,
        cam.D,
        cam.distortion_model,
        cam.R_world_cam,
        cam.t_world_cam,
    )
    if not size_known:
        return resized, None
    dw, dh = cam.width - width, cam.height - height
    if 0 <= dw <= crop_tolerance and 0 <= dh <= crop_tolerance:
        return resized, (
            f'{video.name} is {width}x{height}, camera {cam.name} calibrated at '
            f'{cam.width}x{cam.height}: '
            f'taken as {dw} columns / {dh} rows cropped at the right / bottom, intrinsics '
            'unchanged'
        )
    raise VideoImportError(
        f'{video} is {width}x{height} but camera {cam.name} is calibrated for '
        f'{cam.width}x{cam.height}'
    )


def scaled_camera(cam: Camera, scale: float) -> Camera:
    """Return the camera of images resized by ``scale`` with cv2.resize.

    Camera.scaled, per axis when sizes round.
    """
    small = cam.scaled(scale)
    sx, sy = small.width / cam.width, small.height / cam.height
    if sx == scale and sy == scale:
        return small
    # cv2.resize maps pixel centres with the exact factors sx, sy: u_small = (u + 0.5) sx - 0.5
    K = cam.K.copy()
    K[0, :2] *= sx
    K[1, 1] *= sy
    K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
    K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
    return Camera(
        cam.name,
        small.width,
        small.height,
        K,
        cam.D,
        cam.distortion_model,
        cam.R_world_cam,
        cam.t_world_cam,
    )


def quiet_ffmpeg() -> None:
    """Keep FFmpeg's own log lines off stderr (our errors say what failed in one line).

    Set before first use.
    """
    os.environ.setdefault(
        'OPENCV_FFMPEG_LOGLEVEL', '-8'
    )  # AV_LOG_QUIET, unless the user asks for more


def _open_video(path: Path):
    import cv2

    quiet_ffmpeg()
    if not path.is_file():
        raise VideoImportError(f'no video at {path}')
    capture = cv2.VideoCapture(str(path))
    if not capture.isOpened():
        raise VideoImportError(f'cannot read video {path} (not a video OpenCV can decode)')
    width, height = (
        int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)),
        int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT)),
    )
    if width <= 0 or height <= 0:
        raise VideoImportError(f'cannot read video {path}: no frame size')
    return (
        capture,
        width,
        height,
        float(capture.get(cv2.CAP_PROP_FPS)),
        int(capture.get(cv2.CAP_PROP_FRAME_COUNT)),
    )


def _frames(
    source: VideoSource, first: int, last: int | None, step: int = 1
) -> Iterator[tuple[int, np.ndarray]]:
    """(index, BGR frame) of every step-th frame first <= k < last, decoded one at a time."""
    capture, k = source.capture, 0
    while k < first:  # grab() decodes without converting: exact, unlike seeking
        if not capture.grab():
            return
        k += 1
    while last is None or k < last:
        if (k - first) % step:
            if not capture.grab():
                return
            k += 1
            continue
        ok, frame = capture.read()
        if not ok:
            return
        if frame.shape[:2] != (source.height, source.width):
            raise VideoImportError(
                f'{source.path}: frame {k} is {frame.shape[1]}x{frame.shape[0]}, '
                f'the video said {source.width}x{source.height}'
            )
        yield k, frame
        k += 1


def convert_frame(bgr: np.ndarray, size: tuple[int, int], encoding: str) -> np.ndarray:
    """Return a decoded BGR frame resized to ``size`` (width, height) and in ``encoding``."""
    import cv2

    if (bgr.shape[1], bgr.shape[0]) != size:
        bgr = cv2.resize(bgr, size, interpolation=cv2.INTER_AREA)
    if encoding == 'mono8':
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    return bgr if encoding == 'bgr8' else np.ascontiguousarray(bgr[..., ::-1])


def _resolve_fps(sources: list[VideoSource], fps: float | None) -> float:
    if fps is not None:
        if not fps > 0:
            raise VideoImportError('--fps must be positive')
        return float(fps)
    rates = {s.path.name: s.fps for s in sources}
    if any(not r > 0 for r in rates.values()):
        raise VideoImportError(f'a video has no frame rate ({rates}): pass --fps')
    values = list(rates.values())
    if max(values) - min(values) > 1e-3 * max(values):
        raise VideoImportError(f'the videos have different frame rates {rates}: pass --fps')
    return float(values[0])


def import_videos(
    videos: list[Path],
    calibration: Path,
    out: Path,
    *,
    fmt: str | None = None,
    unit: str = 'm',
    poses: Path | None = None,
    names: list[str] | None = None,
    rename: bool = False,
    fps: float | None = None,
    offsets: dict[str, float] | None = None,
    frames: tuple[int, int | None, int] = (0, None, 1),
    scale: float = 1.0,
    encoding: str = 'mono8',
    crop_tolerance: int = CROP_TOLERANCE,
    body: Body | None = None,
    storage: str = 'mcap',
    force: bool = False,
    progress: bool = False,
) -> ImportResult:
    """Write the bag ``out`` and the studio ``out.yaml``.

    From ``videos``, calibrated by ``calibration``.
    """
    if encoding not in ENCODINGS:
        raise VideoImportError(f'unknown encoding {encoding!r}; known: {", ".join(ENCODINGS)}')
    if not scale > 0:
        raise VideoImportError('--scale must be positive')
    videos = [Path(v) for v in videos]
    calib: Calibration = load_calibration(calibration, fmt=fmt, unit=unit, poses=poses)
    chosen = match_videos(videos, calib.cameras, names)
    if rename:
        chosen = [
            Camera(
                ros_name(v.name.split('.')[0], i),
                c.width,
                c.height,
                c.K,
                c.D,
                c.distortion_model,
                c.R_world_cam,
                c.t_world_cam,
            )
            for i, (v, c) in enumerate(zip(videos, chosen))
        ]
        if len({c.name for c in chosen}) != len(chosen):
            raise VideoImportError('--rename: two videos have the same file stem')
    offsets = dict(offsets or {})
    unknown = sorted(set(offsets) - {c.name for c in chosen})
    if unknown:
        raise VideoImportError(
            f'--offset for unknown camera {", ".join(unknown)} (cameras: '
            f'{", ".join(c.name for c in chosen)})'
        )
    out = Path(out)
    studio_path = out.with_name(out.name + '.yaml')
    if out.exists() and not force:
        raise FileExistsError(f'{out} exists already (use --force to replace it)')
    sources, notes = [], list(calib.notes)
    try:
        for video, cam in zip(videos, chosen):
            capture, width, height, rate, count = _open_video(video)
            sources.append(
                VideoSource(
                    video, cam, capture, width, height, rate, count, offsets.get(cam.name, 0.0)
                )
            )
            sources[-1].camera, note = fit_camera(
                cam, width, height, calib.size_known, crop_tolerance, video
            )
            notes += [note] if note else []
        rate = _resolve_fps(sources, fps)
        cameras = [scaled_camera(s.camera, scale) for s in sources]
        if out.exists():
            shutil.rmtree(out)
        out.parent.mkdir(parents=True, exist_ok=True)
        start = time.perf_counter()
        try:
            counts = _write_bag(sources, cameras, out, rate, frames, encoding, storage, progress)
        except BaseException:
            shutil.rmtree(out, ignore_errors=True)  # no half-written bag left behind
            raise
    finally:
        for source in sources:
            source.capture.release()
    empty = [name for name, n in counts.items() if n == 0]
    if empty:
        shutil.rmtree(out, ignore_errors=True)
        raise VideoImportError(
            f'no frames in range {frames[0]}:{"" if frames[1] is None else frames[1]} for '
            f'{", ".join(empty)}'
        )
    bag_rate = rate / frames[2]  # the bag's images per second: every step-th of the video's
    Studio(ros_name(out.name, 0), cameras, body or load_default_body(), bag_rate).save(studio_path)
    return ImportResult(
        out, studio_path, counts, cameras, bag_rate, time.perf_counter() - start, notes
    )


def _write_bag(
    sources: list[VideoSource],
    cameras: list[Camera],
    out: Path,
    rate: float,
    frames: tuple[int, int | None, int],
    encoding: str,
    storage: str,
    progress: bool,
) -> dict[str, int]:
    """Stream every video's frames into the bag in stamp order; the number of images per camera."""
    first, last, step = frames
    infos = [c.to_camera_info_fields() for c in cameras]
    counts = {c.name: 0 for c in cameras}
    streams = [_frames(s, first, last, step) for s in sources]
    total = sum(
        len(range(first, min(s.frame_count, last or s.frame_count), step)) for s in sources
    )
    bar = Progress(total, 'import', enabled=progress)
    heap = []

    def push(i: int) -> None:
        item = next(streams[i], None)
        if item is not None:
            k, frame = item
            stamp = START_NS + int(round((k / rate + sources[i].offset) * 1e9))
            heapq.heappush(heap, (stamp, i, frame))

    with BagWriter(out, storage) as writer:
        for i in range(len(sources)):
            push(i)
        done = 0
        while heap:
            stamp, i, frame = heapq.heappop(heap)
            cam, info = cameras[i], infos[i]
            pixels = convert_frame(frame, (cam.width, cam.height), encoding)
            writer.write(f'/{cam.name}/camera_info', stamp, camera_info_msg(stamp, info))
            writer.write(
                f'/{cam.name}/image_raw',
                stamp,
                image_msg(stamp, info['frame_id'], pixels, encoding),
            )
            counts[cam.name] += 1
            done += 1
            bar.update(done)
            push(i)
    bar.close()
    return counts
