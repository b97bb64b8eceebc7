"""sensor_msgs/Image messages (rclpy or rosbags flavour) to the numpy arrays the core takes."""

from __future__ import annotations

import numpy as np

from memo_ros.core.vision.encodings import image_to_array, to_grey8

COLOUR_ENCODINGS = ('rgb8', 'bgr8', 'rgba8', 'bgra8')


def image_message_to_grey(msg) -> np.ndarray:
    """Grey levels of a sensor_msgs/Image: decode, then convert."""
    pixels = image_to_array(
        msg.encoding, msg.height, msg.width, msg.step, msg.data, msg.is_bigendian
    )
    return to_grey8(pixels, msg.encoding)


def image_message_to_frame(msg, colour: bool = True) -> np.ndarray:
    """Return a sensor_msgs/Image as the sequence segmenter takes it.

    (H, W, 3) for colour encodings (alpha dropped, channel order kept: the model only compares a
    camera with itself), (H, W) grey otherwise.
    """
    pixels = image_to_array(
        msg.encoding, msg.height, msg.width, msg.step, msg.data, msg.is_bigendian
    )
    if colour and msg.encoding in COLOUR_ENCODINGS:
        return np.ascontiguousarray(pixels[..., :3])
    return to_grey8(pixels, msg.encoding)
