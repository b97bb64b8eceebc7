"""sensor_msgs/Image pixel layouts to numpy arrays, with one-line errors for bad input.

The encodings of DESIGN.md are accepted (mono8, mono16, rgb8, bgr8, rgba8,
bgra8); anything else, a wrong step or a data length that does not match
height * step raises :class:`ImageFormatError` naming the problem.
"""

from __future__ import annotations

import numpy as np

# encoding -> (channels, dtype)
ENCODINGS: dict[str, tuple[int, type]] = {
    'mono8': (1, np.uint8),
    'mono16': (1, np.uint16),
    'rgb8': (3, np.uint8),
    'bgr8': (3, np.uint8),
    'rgba8': (4, np.uint8),
    'bgra8': (4, np.uint8),
}


class ImageFormatError(ValueError):
    """The image message cannot be interpreted as it claims; ``reason`` is a short counter key."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


def image_to_array(
    encoding: str, height: int, width: int, step: int, data, is_bigendian: int = 0
) -> np.ndarray:
    """Return the pixels as (H, W) or (H, W, C) without copying where possible."""
    if encoding not in ENCODINGS:
        raise ImageFormatError(
            'unsupported_encoding',
            f'unsupported encoding {encoding!r} (accepted: {", ".join(ENCODINGS)})',
        )
    channels, dtype = ENCODINGS[encoding]
    row_bytes = width * channels * np.dtype(dtype).itemsize
    if height <= 0 or width <= 0:
        raise ImageFormatError('empty_image', f'empty image {width}x{height}')
    if step < row_bytes:
        raise ImageFormatError(
            'bad_step', f'step {step} is smaller than width*channels*bytes = {row_bytes}'
        )
    buffer = (
        np.frombuffer(data, np.uint8)
        if not isinstance(data, np.ndarray)
        else data.view(np.uint8).ravel()
    )
    if buffer.size != height * step:
        raise ImageFormatError(
            'bad_data_length',
            f'data length {buffer.size} does not match height*step = {height * step}',
        )
    rows = buffer.reshape(height, step)[:, :row_bytes]
    pixels = rows.view(np.dtype(dtype).newbyteorder('>' if is_bigendian else '<'))
    pixels = (
        pixels.reshape(height, width, channels) if channels > 1 else pixels.reshape(height, width)
    )
    return pixels


def to_grey8(pixels: np.ndarray, encoding: str) -> np.ndarray:
    """Grey levels 0..255 (uint8) from any accepted encoding (ITU-R 601 luma for colour)."""
    if encoding == 'mono8':
        return np.ascontiguousarray(pixels)
    if encoding == 'mono16':
        return (pixels.astype(np.uint32) >> 8).astype(np.uint8)
    if encoding in ('rgb8', 'rgba8'):
        r, g, b = pixels[..., 0], pixels[..., 1], pixels[..., 2]
    elif encoding in ('bgr8', 'bgra8'):
        b, g, r = pixels[..., 0], pixels[..., 1], pixels[..., 2]
    else:
        raise ImageFormatError('unsupported_encoding', f'unsupported encoding {encoding!r}')
    luma = (
        299 * r.astype(np.uint32) + 587 * g.astype(np.uint32) + 114 * b.astype(np.uint32) + 500
    ) // 1000
    return luma.astype(np.uint8)
