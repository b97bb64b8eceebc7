"""Export a bag's images as one video per camera plus the calibration in another tool's format.

``memo-ros export videos BAG --out DIR --calibration-format toml`` writes
``DIR/<cam>.mkv`` (FFV1, lossless; or PNG-in-AVI, lossless; or MJPG, lossy but
widely readable) for every camera of the studio ``BAG.yaml`` with images in the
bag, and the studio's cameras as a Qualisys, TOML, EasyMocap or ROS calibration,
so that ``memo-ros import videos`` -- or another mocap tool -- reads them back.
A video has a constant frame rate: a camera's missing frames are filled with its
previous image, and a camera starting late gets an ``--offset`` for the import.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from pathlib import Path
import sys

import numpy as np

from memo_ros.core.formats.calibration import (
    DEFAULT_NAMES,
    FORMATS,
    UNITS,
    CalibrationError,
    write_calibration,
)
from memo_ros.core.formats.studio import Studio
from memo_ros.core.vision.encodings import ImageFormatError, image_to_array
from memo_ros.ros.bagio import (
    BagError,
    bag_topics,
    open_bag,
    read_messages,
    stamp_to_ns,
)
from memo_ros.tools.import_videos import quiet_ffmpeg
from memo_ros.tools.progress import Progress

# codec -> (fourcc, container suffix, lossless)
CODECS = {
    'ffv1': ('FFV1', '.mkv', True),
    'png': ('png ', '.avi', True),
    'mjpg': ('MJPG', '.avi', False),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare this command's arguments and options."""
    parser.add_argument('kind', choices=('videos',), help='what to export: videos')
    parser.add_argument('bag', type=Path, help='rosbag2 with /<cam>/image_raw topics')
    parser.add_argument('--out', '-o', type=Path, required=True, help='output folder')
    parser.add_argument(
        '--calibration-format',
        choices=FORMATS,
        default='toml',
        help='qualisys (Calib.qca.txt), toml (calibration.toml), easymocap (intri.yml + '
        'extri.yml) or ros (<cam>.yaml + poses.yaml); default toml',
    )
    parser.add_argument(
        '--calibration-unit',
        choices=tuple(UNITS),
        default='m',
        help='length unit of toml / EasyMocap translations (default m)',
    )
    parser.add_argument(
        '--studio', type=Path, help='studio YAML with the camera poses (default BAG.yaml)'
    )
    parser.add_argument(
        '--codec',
        choices=tuple(CODECS),
        default='ffv1',
        help='ffv1 (.mkv, lossless, default), png (.avi, lossless) or mjpg (.avi, lossy)',
    )
    parser.add_argument(
        '--force', action='store_true', help='write into an existing output folder'
    )
    parser.add_argument(
        '--progress', action='store_true', help='show progress even when not on a terminal'
    )


@dataclass
class VideoTrack:
    """One camera's video being written."""

    path: Path
    writer: object  # cv2.VideoWriter
    colour: bool
    first_ns: int
    written: int = 0
    filled: int = 0  # frames repeated to cover gaps in the bag
    skipped: int = 0  # images closer than a frame period to the previous one
    last: np.ndarray | None = field(default=None, repr=False)


@dataclass
class ExportResult:
    """What an export wrote."""

    videos: dict[str, Path]
    calibration: list[Path]
    frames: dict[str, int]
    offsets: dict[str, float]
    notes: list[str]


def run(args: argparse.Namespace) -> int:
    """Run the command with parsed ``args``; return its exit code."""
    from memo_ros.tools.cli import CliError

    try:
        result = export_videos(
            args.bag,
            args.out,
            fmt=args.calibration_format,
            unit=args.calibration_unit,
            studio=args.studio,
            codec=args.codec,
            force=args.force,
            progress=args.progress or sys.stderr.isatty(),
        )
    except (
        BagError,
        CalibrationError,
        ImageFormatError,
        VideoExportError,
        FileExistsError,
    ) as exc:
        raise CliError(str(exc)) from None
    for note in result.notes:
        print(f'memo-ros export: warning: {note}', file=sys.stderr)
    for name, path in result.videos.items():
        print(f'video        {path}  ({result.frames[name]} frames)')
    print('calibration  ' + ', '.join(str(p) for p in result.calibration))
    offsets = ''.join(f' --offset {n}={s:.9g}' for n, s in result.offsets.items() if s)
    unit = '' if args.calibration_unit == 'm' else f' --calibration-unit {args.calibration_unit}'
    print(
        f'import with  memo-ros import videos {" ".join(str(p) for p in result.videos.values())} '
        '--calibration '
        f'{result.calibration[0] if len(result.calibration) == 1 else args.out}{unit}{offsets} '
        '--out BAG'
    )
    return 0


class VideoExportError(ValueError):
    """A bag that cannot be exported as asked (a user error, reported in one line)."""


def _message_count(bag: Path, topics: list[str]) -> int:
    """Return the number of messages on ``topics`` from the bag's index, for progress."""
    reader = open_bag(bag)
    try:
        return sum(c.msgcount for c in reader.connections if c.topic in topics)
    finally:
        reader.close()


def _to_video_frame(message, colour: bool) -> np.ndarray:
    """Return the 8-bit grey (H, W) or BGR (H, W, 3) picture of a sensor_msgs/Image."""
    from memo_ros.core.vision.encodings import to_grey8

    pixels = image_to_array(
        message.encoding,
        message.height,
        message.width,
        message.step,
        message.data,
        message.is_bigendian,
    )
    if not colour:
        return to_grey8(pixels, message.encoding)
    if message.encoding in ('mono8', 'mono16'):
        grey = to_grey8(pixels, message.encoding)
        return np.repeat(grey[..., None], 3, axis=2)
    bgr = pixels[..., :3] if message.encoding.startswith('bgr') else pixels[..., 2::-1]
    return np.ascontiguousarray(bgr)


def export_videos(
    bag: Path,
    out: Path,
    fmt: str = 'toml',
    unit: str = 'm',
    studio: Path | None = None,
    codec: str = 'ffv1',
    force: bool = False,
    progress: bool = False,
) -> ExportResult:
    """Write one video per camera of ``bag`` and the calibration as ``fmt`` into folder ``out``."""
    import cv2

    quiet_ffmpeg()
    bag, out = Path(bag), Path(out)
    studio_path = Path(studio) if studio else bag.with_name(bag.name + '.yaml')
    if not studio_path.is_file():
        raise VideoExportError(
            f'no studio file {studio_path} with the camera poses (pass --studio)'
        )
    rig = Studio.load(studio_path)
    topics = bag_topics(bag)
    cameras = [c for c in rig.cameras if f'/{c.name}/image_raw' in topics]
    if not cameras:
        raise VideoExportError(
            f'{bag} has no /<cam>/image_raw topic of the studio cameras '
            f'({", ".join(rig.camera_names)})'
        )
    fourcc, suffix, lossless = CODECS[codec]
    if out.exists() and not force:
        raise FileExistsError(f'{out} exists already (use --force to write into it)')
    out.mkdir(parents=True, exist_ok=True)
    by_topic = {f'/{c.name}/image_raw': c for c in cameras}
    period_ns = 1e9 / rig.frame_rate
    tracks: dict[str, VideoTrack] = {}
    notes = [] if lossless else [f"{codec} is lossy: imported images will differ from the bag's"]
    notes += [
        f'{c.name}: no /{c.name}/image_raw in the bag, not exported'
        for c in rig.cameras
        if c not in cameras
    ]
    bar = Progress(_message_count(bag, list(by_topic)), 'export', enabled=progress)
    try:
        for done, m in enumerate(read_messages(bag, list(by_topic)), 1):
            cam = by_topic[m.topic]
            msg, stamp = m.message, stamp_to_ns(m.message.header.stamp)
            if (msg.width, msg.height) != (cam.width, cam.height):
                raise VideoExportError(
                    f'{m.topic}: {msg.width}x{msg.height} images but the studio calibrates '
                    f'{cam.name} at {cam.width}x{cam.height}'
                )
            track = tracks.get(cam.name)
            if track is None:
                colour = msg.encoding not in ('mono8', 'mono16')
                path = out / f'{cam.name}{suffix}'
                writer = cv2.VideoWriter(
                    str(path),
                    cv2.VideoWriter_fourcc(*fourcc),
                    rig.frame_rate,
                    (cam.width, cam.height),
                    colour,
                )
                if not writer.isOpened():
                    raise VideoExportError(f'OpenCV cannot write {codec} video {path}')
                track = tracks[cam.name] = VideoTrack(path, writer, colour, stamp)
                if msg.encoding == 'mono16':
                    notes.append(f'{cam.name}: mono16 images exported as 8-bit grey')
            frame = _to_video_frame(msg, track.colour)
            index = int(round((stamp - track.first_ns) / period_ns))
            if index < track.written:  # closer than a frame period to the previous image
                track.skipped += 1
                continue
            while track.written < index:  # a gap: hold the previous image, keeping the frame clock
                track.writer.write(track.last)
                track.written += 1
                track.filled += 1
            track.writer.write(frame)
            track.written += 1
            track.last = frame
            bar.update(done)
    finally:
        for track in tracks.values():
            track.writer.release()
        bar.close()
    for name, track in tracks.items():
        if track.filled or track.skipped:
            notes.append(
                f'{name}: {track.filled} missing frames filled with the previous image, '
                f'{track.skipped} images dropped as closer than 1/{rig.frame_rate:g} s to the '
                'previous one'
            )
    exported = [c for c in cameras if c.name in tracks]
    calibration = write_calibration(exported, out / DEFAULT_NAMES[fmt], fmt, unit)
    start = min(t.first_ns for t in tracks.values())
    return ExportResult(
        {c.name: tracks[c.name].path for c in exported},
        calibration,
        {c.name: tracks[c.name].written for c in exported},
        {c.name: (tracks[c.name].first_ns - start) / 1e9 for c in exported},
        notes,
    )
