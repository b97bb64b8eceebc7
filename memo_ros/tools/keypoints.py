"""2D body keypoints of a recording's images by a learned detector (mediapipe's BlazePose).

The detector's weights ship inside the mediapipe wheel (``pip install
memo_ros[keypoints]``); nothing is downloaded at run time, and no node
imports this module.  Only model complexity 1 ('full') is in the 0.10.14
wheel: 0 ('lite') and 2 ('heavy') would be fetched from the web.  Detections
are cached beside the estimate, keyed by the recording, so a second
evaluation is fast.

mediapipe 0.10.14 requires opencv-contrib-python, jax, jaxlib and sounddevice,
none of which BlazePose needs here; opencv-contrib-python also installs a
second ``cv2`` (a GUI build wanting libGL) over opencv-python-headless's.
``scripts/setup.sh`` therefore installs it as::

    pip install -c constraints.txt -e '.[test]'
    pip install --no-deps -c constraints.txt mediapipe absl-py attrs flatbuffers protobuf
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
import hashlib
import os
from pathlib import Path
import sys
import tempfile
import warnings

import numpy as np

from memo_ros.core.evaluation.keypoints import BLAZEPOSE
from memo_ros.ros.bagio import read_messages, stamp_to_ns
from memo_ros.ros.images import image_message_to_frame

KEYPOINT_NAMES: tuple[str, ...] = tuple(BLAZEPOSE)
MODEL_COMPLEXITY = 1  # 'full': the heavy model (2) is not in the wheel and would be downloaded


class KeypointsUnavailable(RuntimeError):
    """The optional detector is not installed."""


@dataclass
class Detections:
    """Keypoints of every camera and frame.

    Pixels (C, F, K, 2), confidence (C, F, K), stamps (F,).
    """

    cameras: list[str]
    stamps: np.ndarray
    uv: np.ndarray
    confidence: np.ndarray


@contextmanager
def _native_logs_quiet() -> Iterator[None]:
    """Keep TFLite's and glog's lines (written by C++ straight to fd 2) off the user's terminal.

    They are informational (an XNNPACK delegate was created, a feedback
    manager disabled) and no environment variable silences them; with
    MEMO_ROS_DEBUG set they are shown.
    """
    if os.environ.get('MEMO_ROS_DEBUG'):
        yield
        return
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with tempfile.TemporaryFile() as scratch, warnings.catch_warnings():
            warnings.filterwarnings('ignore', 'SymbolDatabase.GetPrototype', UserWarning)
            os.dup2(scratch.fileno(), 2)
            try:
                yield
            finally:
                sys.stderr.flush()
                os.dup2(saved, 2)
    finally:
        os.close(saved)


def _pose_estimator():
    """Return a mediapipe Pose in image mode (one detection per picture).

    Raise :class:`KeypointsUnavailable` saying how to install it when it is missing.
    """
    try:
        from mediapipe.python.solutions.pose import Pose
    except ImportError as exc:
        raise KeypointsUnavailable(
            f'the keypoint detector is not installed ({exc}): pip install memo_ros[keypoints] '
            '(scripts/setup.sh installs it without opencv-contrib-python)'
        ) from None
    return Pose(static_image_mode=True, model_complexity=MODEL_COMPLEXITY)


def detect(bag: Path, cameras: list[str], cache: Path | None = None) -> Detections:
    """Detect the keypoints in every camera's images of ``bag`` (frames all cameras share)."""
    key = _cache_key(bag, cameras)
    if cache is not None and cache.is_file():
        with np.load(cache, allow_pickle=False) as data:
            if str(data['key']) == key:
                return Detections(
                    list(data['cameras']), data['stamps'], data['uv'], data['confidence']
                )
    topics = {f'/{c}/image_raw': k for k, c in enumerate(cameras)}
    found: dict[int, dict[int, tuple[np.ndarray, np.ndarray]]] = {}
    with _native_logs_quiet(), _pose_estimator() as pose:
        for m in read_messages(bag, list(topics)):
            frame = image_message_to_frame(m.message)
            found.setdefault(stamp_to_ns(m.message.header.stamp), {})[topics[m.topic]] = _detect(
                pose, frame, m.message.encoding
            )
    stamps = np.array(sorted(s for s, per in found.items() if len(per) == len(cameras)), np.int64)
    n = len(KEYPOINT_NAMES)
    uv = np.full((len(cameras), len(stamps), n, 2), np.nan)
    confidence = np.zeros((len(cameras), len(stamps), n))
    for f, stamp in enumerate(stamps):
        for c, (points, conf) in found[int(stamp)].items():
            uv[c, f], confidence[c, f] = points, conf
    detections = Detections(list(cameras), stamps, uv, confidence)
    if cache is not None:
        cache.parent.mkdir(parents=True, exist_ok=True)
        np.savez(
            cache, key=key, cameras=np.array(cameras), stamps=stamps, uv=uv, confidence=confidence
        )
    return detections


def _detect(pose, frame: np.ndarray, encoding: str) -> tuple[np.ndarray, np.ndarray]:
    """Return one picture's keypoints (K, 2) in pixels and their visibilities (K,)."""
    import cv2

    if frame.ndim == 2:
        rgb = cv2.cvtColor(frame, cv2.COLOR_GRAY2RGB)
    elif encoding.startswith('bgr'):
        rgb = cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)
    else:
        rgb = np.ascontiguousarray(frame[..., :3])
    height, width = rgb.shape[:2]
    result = pose.process(rgb)
    n = len(KEYPOINT_NAMES)
    if result.pose_landmarks is None:
        return np.full((n, 2), np.nan), np.zeros(n)
    marks = result.pose_landmarks.landmark
    points = np.array([[marks[i].x * width, marks[i].y * height] for i in BLAZEPOSE.values()])
    return points, np.array([marks[i].visibility for i in BLAZEPOSE.values()])


def _cache_key(bag: Path, cameras: list[str]) -> str:
    """Return what a cached detection must match: the bag's files, their sizes and times."""
    parts = [f'{MODEL_COMPLEXITY}', *cameras]
    for path in sorted(Path(bag).glob('*')):
        stat = path.stat()
        parts.append(f'{path.name}:{stat.st_size}:{stat.st_mtime_ns}')
    return hashlib.sha256('|'.join(parts).encode()).hexdigest()
