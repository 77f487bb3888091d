"""Images to calibrate from: a folder of image files, a video file, or a rosbag2 bag.

``open_source(path, topic)`` decides by what ``path`` is (a folder of images, a bag folder
or ``.mcap`` file, anything else a video file) and returns an iterator of ``(label,
image)``: a BGR or grey uint8 image and where it came from (file name, frame number, bag
time). Every problem a user can cause (no such path, a file OpenCV cannot read, a bag without
the topic or with a topic of another type) is a ``CalibrationError`` naming the path. A bag
is read with ``rosbags`` (sensor_msgs/msg/Image in the encodings a camera gives, or
sensor_msgs/msg/CompressedImage). No ROS.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from enbarr_core.framework.errors import CalibrationError

#: What a folder's images may end with (what ``cv2.imread`` reads).
IMAGE_SUFFIXES = ('.png', '.jpg', '.jpeg', '.bmp', '.pgm', '.ppm', '.pnm', '.tif', '.tiff',
                  '.webp')
IMAGE_TYPE = 'sensor_msgs/msg/Image'
COMPRESSED_TYPE = 'sensor_msgs/msg/CompressedImage'

Frames = Iterator[tuple[str, np.ndarray]]


def is_bag(path: Path) -> bool:
    """Whether ``path`` is a rosbag2 bag (a folder with metadata.yaml, or an .mcap file)."""
    return (path.is_dir() and (path / 'metadata.yaml').is_file()) or (
        path.is_file() and path.suffix == '.mcap')


def open_source(path: str, topic: str = 'camera/image_raw') -> Frames:
    """Return the images of ``path`` (a folder of images, a bag, a video file); see above."""
    p = Path(path)
    if not p.exists():
        raise CalibrationError(f'{path}: no such file or folder')
    if is_bag(p):
        return read_bag(p, topic)
    if p.is_dir():
        return read_folder(p)
    return read_video(p)


def read_folder(folder: Path) -> Frames:
    """Return the images of ``folder`` in name order; a file that does not decode is an error."""
    files = sorted(f for f in folder.iterdir()
                   if f.is_file() and f.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise CalibrationError(f'{folder}: no image files ({", ".join(IMAGE_SUFFIXES)})')

    def frames() -> Frames:
        for f in files:
            image = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
            if image is None:
                raise CalibrationError(f'{f}: not an image OpenCV can read')
            yield f.name, _to_uint8(image, str(f))
    return frames()


def read_video(path: Path) -> Frames:
    """Return the frames of a video file; one that OpenCV cannot open is an error."""
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        cap.release()
        raise CalibrationError(f'{path}: not a video, image folder or bag OpenCV or rosbags '
                               'can read')

    def frames() -> Frames:
        n = 0
        try:
            while True:
                ok, frame = cap.read()
                if not ok:
                    break
                yield f'frame {n}', frame
                n += 1
        finally:
            cap.release()
        if n == 0:
            raise CalibrationError(f'{path}: no frame could be read from the video')
    return frames()


def read_bag(path: Path, topic: str) -> Frames:
    """Return the images on ``topic`` of a bag (Image or CompressedImage)."""
    from rosbags.rosbag2 import Reader
    from rosbags.rosbag2.errors import ReaderError
    from rosbags.typesys import get_typestore, Stores

    name = topic if topic.startswith('/') else f'/{topic}'
    typestore = get_typestore(Stores.ROS2_JAZZY)
    try:
        reader = Reader(path)
        reader.open()
    except (ReaderError, OSError) as err:
        raise CalibrationError(f'{path}: not a bag rosbags can read: {err}') from err
    conns = [c for c in reader.connections if c.topic == name]
    if not conns:
        images = sorted(c.topic for c in reader.connections
                        if c.msgtype in (IMAGE_TYPE, COMPRESSED_TYPE))
        reader.close()
        raise CalibrationError(f'{path}: no topic {name}; the image topics in it: '
                               f'{", ".join(images) or "none"}')
    if conns[0].msgtype not in (IMAGE_TYPE, COMPRESSED_TYPE):
        reader.close()
        raise CalibrationError(f'{path}: {name} is {conns[0].msgtype}, not {IMAGE_TYPE} or '
                               f'{COMPRESSED_TYPE}')

    def frames() -> Frames:
        try:
            for conn, t, raw in reader.messages(connections=conns):
                try:
                    msg = typestore.deserialize_cdr(raw, conn.msgtype)
                except Exception as err:  # noqa: BLE001 - rosbags raises several kinds
                    raise CalibrationError(f'{path}: {name} at {t} ns: cannot decode: '
                                           f'{err}') from err
                label = f'{name} at {t * 1e-9:.3f} s'
                yield label, (decode_compressed(msg, f'{path}: {label}')
                              if conn.msgtype == COMPRESSED_TYPE
                              else decode_image(msg, f'{path}: {label}'))
        finally:
            reader.close()
    return frames()


def decode_image(msg: Any, where: str) -> np.ndarray:
    """Return a sensor_msgs/Image (any object with its fields) as BGR or grey uint8."""
    enc = str(msg.encoding).lower()
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.frombuffer(bytes(msg.data), dtype=np.uint8)
    channels = {'mono8': 1, '8uc1': 1, 'bgr8': 3, 'rgb8': 3, '8uc3': 3, 'bgra8': 4,
                'rgba8': 4, 'mono16': 2, '16uc1': 2}.get(enc)
    if channels is None:
        raise CalibrationError(f'{where}: image encoding {msg.encoding!r} is not one of mono8, '
                               'mono16, bgr8, rgb8, bgra8, rgba8')
    if h <= 0 or w <= 0 or step < w * channels or len(data) < step * h:
        raise CalibrationError(f'{where}: {w}x{h} image with step {step} and {len(data)} bytes')
    rows = data[:step * h].reshape(h, step)[:, :w * channels]
    if channels == 2:   # 16-bit grey: keep the high byte, as camera_calibration's mkgray does
        big = bool(msg.is_bigendian)
        return (np.frombuffer(rows.tobytes(), dtype='>u2' if big else '<u2')
                .reshape(h, w) >> 8).astype(np.uint8)
    img = rows.reshape(h, w, channels) if channels > 1 else rows.reshape(h, w)
    if enc == 'rgb8':
        return cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    if enc == 'rgba8':
        return cv2.cvtColor(img, cv2.COLOR_RGBA2BGR)
    if enc == 'bgra8':
        return cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    return np.ascontiguousarray(img)


def decode_compressed(msg: Any, where: str) -> np.ndarray:
    """Return a sensor_msgs/CompressedImage (JPEG, PNG) as BGR or grey uint8."""
    image = cv2.imdecode(np.frombuffer(bytes(msg.data), dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise CalibrationError(f'{where}: compressed image ({msg.format!r}) OpenCV cannot '
                               'decode')
    return _to_uint8(image, where)


def _to_uint8(image: np.ndarray, where: str) -> np.ndarray:
    if image.dtype == np.uint16:
        return (image >> 8).astype(np.uint8)
    if image.dtype != np.uint8:
        raise CalibrationError(f'{where}: {image.dtype} pixels; 8- or 16-bit expected')
    return image
