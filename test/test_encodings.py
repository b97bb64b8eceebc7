"""Image message layouts: every accepted encoding decodes; bad input names its problem."""

import numpy as np
import pytest

from memo_ros.core.vision.encodings import (
    ENCODINGS,
    ImageFormatError,
    image_to_array,
    to_grey8,
)


def _grey_and_colour():
    rng = np.random.default_rng(0)
    grey = rng.integers(0, 256, (5, 7), dtype=np.uint8)
    return grey, np.repeat(grey[..., None], 3, axis=2)


@pytest.mark.parametrize('encoding', sorted(ENCODINGS))
def test_every_encoding_decodes_to_the_same_grey(encoding):
    grey, bgr = _grey_and_colour()
    pixels = {
        'mono8': grey,
        'mono16': grey.astype(np.uint16) * 257,
        'bgr8': bgr,
        'rgb8': bgr,
        'bgra8': np.dstack([bgr, np.full_like(grey, 255)]),
        'rgba8': np.dstack([bgr, np.full_like(grey, 255)]),
    }[encoding]
    step = pixels.strides[0] + 3  # rows padded: step larger than the row
    data = np.zeros(pixels.shape[0] * step, np.uint8)
    rows = data.reshape(pixels.shape[0], step)
    rows[:, : pixels.strides[0]] = pixels.view(np.uint8).reshape(pixels.shape[0], -1)
    decoded = image_to_array(encoding, grey.shape[0], grey.shape[1], step, data.tobytes())
    assert np.array_equal(to_grey8(decoded, encoding), grey)


def test_big_endian_mono16():
    values = np.array([[0x0102, 0xFF00]], np.uint16)
    decoded = image_to_array('mono16', 1, 2, 4, values.astype('>u2').tobytes(), is_bigendian=1)
    assert decoded.tolist() == [[0x0102, 0xFF00]]


@pytest.mark.parametrize(
    'args, reason',
    [
        (('yuv422', 2, 2, 4, bytes(8)), 'unsupported_encoding'),
        (('mono8', 2, 4, 3, bytes(6)), 'bad_step'),
        (('mono8', 2, 4, 4, bytes(7)), 'bad_data_length'),
        (('rgb8', 0, 4, 12, b''), 'empty_image'),
    ],
)
def test_bad_images_raise_a_reason(args, reason):
    with pytest.raises(ImageFormatError) as info:
        image_to_array(*args)
    assert info.value.reason == reason and str(info.value)
