"""A learnt background on disk: a grey PNG and, beside it, a record of how it was learnt.

A background learnt while a person stood in view holds that person, and every later session
that loads it is blind where he stood.  So a background is written only with its record
(``PATH.yaml``: the frames it came from, how many pixels moved in them, whether a tracked body
was in view), and a file is used only when that record says it was learnt from an empty scene.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
import os
from pathlib import Path

import cv2
import numpy as np
import yaml

FORMAT = 'memo_ros background 1'


class BackgroundFileError(ValueError):
    """A background file that must not be used, with the reason in one line."""


@dataclass
class BackgroundRecord:
    """How a background was learnt: what decides whether it shows the empty scene."""

    camera: str
    width: int
    height: int
    frames: int  # frames it was learnt from
    moved_pixels: int  # the most pixels that moved in one of them (a person in view moves)
    tracked_body_in_view: bool  # the tracker's body projected into the image while learning
    max_moved_pixels: int  # the limit it was judged by

    @property
    def empty_scene(self) -> bool:
        """True when nothing moved and no tracked body was in view while it was learnt."""
        return self.moved_pixels < self.max_moved_pixels and not self.tracked_body_in_view

    def why_not_empty(self) -> str:
        """Say in a few words what showed a person while it was learnt."""
        if self.tracked_body_in_view:
            return "the tracked body was in the camera's view"
        return f'{self.moved_pixels} pixels moved (limit {self.max_moved_pixels})'


def record_path(path: str | Path) -> Path:
    """Return the record written beside a background PNG."""
    return Path(f'{path}.yaml')


def save_background(path: str | Path, image: np.ndarray, record: BackgroundRecord) -> None:
    """Write the PNG and its record, each atomically; refuse a background of an occupied scene."""
    if not record.empty_scene:
        raise BackgroundFileError(f'not saved: while it was learnt {record.why_not_empty()}')
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(f'{path}.tmp.png')
    if not cv2.imwrite(str(tmp), image):
        raise OSError(f'cv2.imwrite could not write {tmp}')
    os.replace(tmp, path)
    meta = record_path(path)
    tmp_meta = Path(f'{meta}.tmp')
    tmp_meta.write_text(yaml.safe_dump({'format': FORMAT, **asdict(record)}, sort_keys=False))
    os.replace(tmp_meta, meta)


def load_background(path: str | Path, width: int | None = None, height: int | None = None):
    """Return (grey image, record) of a background learnt from an empty scene.

    Raises BackgroundFileError, with the reason in one line, for an unreadable image, a missing
    or foreign record, a size that is not the camera's, or a scene that was not empty.
    """
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise BackgroundFileError(f'{path} is not a readable image')
    meta = record_path(path)
    try:
        data = yaml.safe_load(meta.read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        raise BackgroundFileError(
            f'{path} has no readable record {meta.name} saying it was learnt from an empty '
            'scene (a picture taken with a person in view would blind the camera there)'
        ) from None
    if not isinstance(data, dict) or data.pop('format', None) != FORMAT:
        raise BackgroundFileError(f'{meta} is not a {FORMAT!r} record')
    try:
        record = BackgroundRecord(**data)
    except TypeError as exc:
        raise BackgroundFileError(f'{meta}: {exc}') from None
    if (record.width, record.height) != (image.shape[1], image.shape[0]):
        raise BackgroundFileError(
            f'{path} is {image.shape[1]}x{image.shape[0]} but its record says '
            f'{record.width}x{record.height}'
        )
    if (
        width is not None
        and height is not None
        and (width, height) != (record.width, record.height)
    ):
        raise BackgroundFileError(
            f'{path} is {record.width}x{record.height}, the camera {width}x{height}'
        )
    if not record.empty_scene:
        raise BackgroundFileError(
            f'{path} was learnt with a person in view ({record.why_not_empty()})'
        )
    return image, record
