"""A learnt background is saved only from an empty scene and loaded only with that record."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from memo_ros.core.formats.background_file import (
    BackgroundFileError,
    BackgroundRecord,
    load_background,
    record_path,
    save_background,
)
from memo_ros.core.vision.segmentation import BackgroundSegmenter, moved_pixels


def _record(**changes) -> BackgroundRecord:
    empty_vga_corner = BackgroundRecord('cam', 64, 48, 3, 0, False, 200)
    return replace(empty_vga_corner, **changes)


def _scene(rng) -> np.ndarray:
    return rng.integers(90, 110, (48, 64), dtype=np.uint8)


def test_an_empty_scene_round_trips(tmp_path):
    image = _scene(np.random.default_rng(0))
    save_background(tmp_path / 'bg.png', image, _record())
    loaded, record = load_background(tmp_path / 'bg.png', 64, 48)
    assert np.array_equal(loaded, image) and record == _record()


@pytest.mark.parametrize(
    'record',
    [_record(moved_pixels=200), _record(tracked_body_in_view=True)],
    ids=['moved', 'body'],
)
def test_an_occupied_scene_is_not_saved(tmp_path, record):
    with pytest.raises(BackgroundFileError, match='not saved'):
        save_background(tmp_path / 'bg.png', _scene(np.random.default_rng(0)), record)
    assert not (tmp_path / 'bg.png').exists()


def test_a_file_without_its_record_or_with_a_person_is_refused(tmp_path):
    path = tmp_path / 'bg.png'
    cv2.imwrite(str(path), _scene(np.random.default_rng(0)))
    with pytest.raises(BackgroundFileError, match='no readable record'):
        load_background(path)
    record_path(path).write_text(
        'format: memo_ros background 1\n'
        + '\n'.join(f'{k}: {v}' for k, v in vars(_record(moved_pixels=5000)).items())
    )
    with pytest.raises(BackgroundFileError, match='person in view'):
        load_background(path)
    save_background(path, _scene(np.random.default_rng(1)), _record())
    with pytest.raises(BackgroundFileError, match='the camera 640x480'):
        load_background(path, 640, 480)
    path.write_bytes(b'not a png')
    with pytest.raises(BackgroundFileError, match='not a readable image'):
        load_background(path)


def test_moved_pixels_sees_a_person_who_moves_and_not_sensor_noise():
    rng = np.random.default_rng(2)
    empty = np.stack([_scene(rng) for _ in range(5)])
    segmenter = BackgroundSegmenter(learn_frames=5)
    for frame in empty:
        segmenter.segment(frame)
    assert segmenter.moved_pixels == 0
    frames = empty.copy()
    for k, frame in enumerate(frames):  # a 30x14 block walking 4 px a frame
        frame[10:40, 10 + 4 * k : 24 + 4 * k] = 200
    background = np.median(frames, axis=0).round().astype(np.uint8)
    assert moved_pixels(frames, background) >= 2 * 30 * 8
