"""What every camera publishes, real or simulated: the image, its JPEG and its calibration.

``ImageOutput`` publishes one frame (a BGR ``uint8`` array) as
- ``camera/image_raw`` (``sensor_msgs/Image``, bgr8), unless ``publish_raw`` is false;
- ``camera/image_raw/compressed`` (``sensor_msgs/CompressedImage``), the JPEG as
  image_transport's compressed plugin publishes it: ``format`` is the raw encoding, then
  ``'; jpeg compressed '`` and the target encoding (``bgr8`` for colour), i.e.
  ``'bgr8; jpeg compressed bgr8'`` (ros-perception/image_transport_plugins,
  compressed_image_transport/src/compressed_publisher.cpp), so ``image_transport``'s
  republisher, Foxglove and ``rqt_image_view`` decode it;
- ``camera/camera_info``, with the same header.
``store_camera_info`` is every camera's ``camera/set_camera_info`` (camera_info_manager's
service, the calibration "commit"): check the CameraInfo, write it to the ``calibration_file``
and answer, the real driver and the simulated camera alike.
Like image_transport, a topic nobody subscribes to costs nothing: the image is converted and
the JPEG encoded only while the topic has a subscriber (the recorder is one). A raw 640x480
stream is about 14 MB/s, more than a Raspberry Pi's SD card keeps up with; its JPEG is a
tenth of that or less (docs/benchmarks.md, "The camera").
"""

from __future__ import annotations

from typing import Any, Protocol

import cv2
import numpy as np
from numpy.typing import NDArray
from sensor_msgs.msg import CameraInfo, CompressedImage, Image

from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces import topics
from enbarr_plugins.camera.calibration import Calibration, calibration_of, save_calibration

#: The ``format`` of a colour JPEG in image_transport's compressed transport.
JPEG_FORMAT = 'bgr8; jpeg compressed bgr8'

#: The parameters of what a camera publishes (each camera node declares them).
OUTPUT_SPECS = [
    ParamSpec('jpeg_quality', 80, 'JPEG quality of camera/image_raw/compressed (as '
              "image_transport's jpeg_quality; lower: smaller and cheaper)", '', 1, 100),
    ParamSpec('publish_raw', True, 'Also publish camera/image_raw (bgr8, about 14 MB/s at '
              '640x480 and 15 fps); false: the JPEG and the camera_info only',
              read_only=True),
]


def camera_info(cal: Calibration | None, width: int, height: int) -> CameraInfo:
    """Return the CameraInfo of a frame (the calibration's when it has this size)."""
    info = CameraInfo()
    info.width, info.height = width, height
    if cal is not None and (cal.width, cal.height) == (width, height):
        info.distortion_model = cal.distortion_model
        info.d = list(cal.d)
        info.k = list(cal.k)
        info.r = list(cal.r)
        info.p = list(cal.p)
    return info


class _Request(Protocol):
    camera_info: CameraInfo


class _Response(Protocol):
    success: bool
    status_message: str


def store_camera_info(node: EnbarrNode, device: str, path: str, old: Calibration | None,
                      frame_size: tuple[int, int] | None, request: _Request,
                      response: _Response) -> Calibration | None:
    """Serve one ``set_camera_info``: store ``request.camera_info`` in ``path``, answer.

    Returns the calibration stored (the caller publishes it from then on), or ``None`` with
    ``response.success`` false and the reason in ``response.status_message``: no ``path``,
    a malformed CameraInfo, an image size other than ``frame_size`` (the frames'; ``None``:
    not known yet), or a file that cannot be written. ``old`` names the camera in the file.
    """
    try:
        if not path:
            raise ValueError('no calibration_file is configured: nowhere to store it')
        cal = calibration_of(request.camera_info,
                             old.camera_name if old is not None else 'camera')
        if frame_size is not None and (cal.width, cal.height) != frame_size:
            w, h = frame_size
            raise ValueError(f'calibration for {cal.width}x{cal.height} images, but the '
                             f'camera gives {w}x{h}')
        save_calibration(cal, path)
    except (ValueError, OSError) as err:
        reason = (f'{path}: cannot write: {err.strerror or err}'
                  if isinstance(err, OSError) else str(err))
        node.get_logger().warn(f'{device}: set_camera_info refused: {reason}')
        response.success, response.status_message = False, reason
        return None
    node.get_logger().info(f'{device}: calibration stored in {path}')
    response.success, response.status_message = True, f'stored in {path}'
    return cal


def encode_jpeg(frame: NDArray[np.uint8], quality: int) -> bytes:
    """Return the JPEG of a BGR frame (OpenCV's encoder, as image_transport uses)."""
    ok, data = cv2.imencode('.jpg', frame, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError('cv2.imencode could not encode the frame as JPEG')
    return bytes(data)


class ImageOutput:
    """The publishers of one camera (see the module docstring)."""

    def __init__(self, node: EnbarrNode, publish_raw: bool) -> None:
        self._raw: Any = node.create_topic_publisher(topics.CAMERA_IMAGE) if publish_raw \
            else None
        self._jpeg: Any = node.create_topic_publisher(topics.CAMERA_COMPRESSED)
        self._info: Any = node.create_topic_publisher(topics.CAMERA_INFO)
        self.encoded = 0

    def publish(self, frame: NDArray[np.uint8], stamp: Any, info: CameraInfo,
                jpeg_quality: int) -> None:
        """Publish ``frame`` stamped ``stamp`` (builtin_interfaces/Time) and its ``info``."""
        h, w = frame.shape[:2]
        frame_id = topics.CAMERA_IMAGE.frame
        if self._raw is not None and self._raw.get_subscription_count() > 0:
            img = Image()
            img.header.stamp = stamp
            img.header.frame_id = frame_id
            img.height, img.width = h, w
            img.encoding = 'bgr8'
            img.is_bigendian = 0
            img.step = w * 3
            img.data = frame.tobytes()
            self._raw.publish(img)
        if self._jpeg.get_subscription_count() > 0:
            jpeg = CompressedImage()
            jpeg.header.stamp = stamp
            jpeg.header.frame_id = frame_id
            jpeg.format = JPEG_FORMAT
            jpeg.data = encode_jpeg(frame, jpeg_quality)
            self._jpeg.publish(jpeg)
            self.encoded += 1
        info.header.stamp = stamp
        info.header.frame_id = frame_id
        self._info.publish(info)
