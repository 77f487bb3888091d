"""Camera images between ROS messages and OpenCV arrays (BGR, ``uint8``, rows x cols x 3).

``sensor_msgs/Image`` in the encodings a camera gives (``bgr8``, ``rgb8``, ``mono8``,
``bgra8``, ``rgba8``) and ``sensor_msgs/CompressedImage`` (``format`` JPEG or PNG: whatever
``cv2.imdecode`` reads). Anything else is an :class:`ImageEncodingError` naming it.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray
from sensor_msgs.msg import CompressedImage, Image

#: encoding -> (channels, conversion to BGR or None)
_ENCODINGS = {'bgr8': (3, None), 'rgb8': (3, cv2.COLOR_RGB2BGR),
              'mono8': (1, cv2.COLOR_GRAY2BGR), 'bgra8': (4, cv2.COLOR_BGRA2BGR),
              'rgba8': (4, cv2.COLOR_RGBA2BGR)}


class ImageEncodingError(ValueError):
    """An image message this module cannot turn into BGR pixels (names what is wrong)."""


def image_to_bgr(msg: Image) -> NDArray[np.uint8]:
    """Return the pixels of an ``Image`` as BGR: a writeable copy (callers draw on it).

    Any object with ``Image``'s fields will do (a message as ``rosbags`` reads it).
    """
    enc = _ENCODINGS.get(msg.encoding)
    if enc is None:
        raise ImageEncodingError(f'image encoding {msg.encoding!r} is not read (one of '
                                 f'{", ".join(_ENCODINGS)})')
    channels, code = enc
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.frombuffer(bytes(msg.data), dtype=np.uint8)
    if w < 1 or h < 1 or step < w * channels or len(data) < h * step:
        raise ImageEncodingError(f'image {w} x {h} {msg.encoding}: step {step}, {len(data)} '
                                 'bytes do not hold it')
    rows = data[:h * step].reshape(h, step)[:, :w * channels]
    pixels = rows.reshape(h, w, channels) if channels > 1 else rows.reshape(h, w)
    if code is None:
        return pixels.copy()    # the message's buffer is read-only
    return np.asarray(cv2.cvtColor(pixels, code), dtype=np.uint8)


def bgr_to_image(pixels: NDArray[np.uint8], out: Image | None = None) -> Image:
    """Return a ``bgr8`` ``Image`` of BGR pixels (header left to the caller)."""
    msg = out if out is not None else Image()
    h, w = pixels.shape[:2]
    msg.height, msg.width = h, w
    msg.encoding = 'bgr8'
    msg.is_bigendian = 0
    msg.step = w * 3
    msg.data = np.ascontiguousarray(pixels).tobytes()
    return msg


def compressed_to_bgr(msg: CompressedImage) -> NDArray[np.uint8]:
    """Return the pixels of a ``CompressedImage`` (JPEG, PNG) as BGR.

    Any object with its ``format`` and ``data`` will do.
    """
    data = np.frombuffer(bytes(msg.data), dtype=np.uint8)
    pixels = cv2.imdecode(data, cv2.IMREAD_COLOR) if len(data) else None
    if pixels is None:
        raise ImageEncodingError(f'compressed image ({msg.format!r}, {len(data)} bytes) '
                                 'cannot be decoded')
    return np.asarray(pixels, dtype=np.uint8)
