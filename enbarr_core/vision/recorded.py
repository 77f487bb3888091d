"""Camera and lidar data for calibration from a bag (rosbag2: our recorder's MCAP, or SQLite).

Messages as the ``rosbags`` reader gives them (no ROS needed): ``sensor_msgs/LaserScan`` and
``sensor_msgs/Image`` or ``sensor_msgs/CompressedImage``, in time order and one at a time, so
that a long bag of images is never held in memory. ``board_poses`` turns them into what
``extrinsics.solve_planes`` needs: the times the checkerboard was held still, its corners
there (averaged over the still images) and the scans taken meanwhile.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
import os
from typing import Any

import numpy as np
from numpy.typing import NDArray

from enbarr_core.framework.errors import CalibrationError
from enbarr_core.perception.scan_geometry import scan_points
from enbarr_core.vision.board import Board
from enbarr_core.vision.intrinsics import find_corners
from enbarr_interfaces.image_msgs import compressed_to_bgr, image_to_bgr, ImageEncodingError

IMAGE_TYPES = ('sensor_msgs/msg/Image', 'sensor_msgs/msg/CompressedImage')
SCAN_TYPE = 'sensor_msgs/msg/LaserScan'


def stamp_ns(msg: Any) -> int:
    """Return the message's header stamp [ns]."""
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def image_array(msg: Any) -> NDArray[np.uint8]:
    """Decode a BGR image (H, W, 3) from an Image or CompressedImage message (a copy)."""
    try:
        if hasattr(msg, 'format'):   # CompressedImage
            return compressed_to_bgr(msg)
        return image_to_bgr(msg)
    except ImageEncodingError as err:
        raise CalibrationError(str(err)) from err


def scan_xy(msg: Any) -> NDArray[np.float64]:
    """Return the finite points (N, 2) [m] of a LaserScan in its frame, in ring order."""
    return scan_points(np.asarray(msg.ranges, dtype=float), float(msg.angle_min),
                       float(msg.angle_increment)).laser


@dataclass(frozen=True)
class Topics:
    """Which topics of a bag hold the scan and the images (resolved by ``bag_topics``)."""

    scan: str
    image: str


def bag_topics(path: str | os.PathLike[str], scan: str = '', image: str = '') -> Topics:
    """Resolve the scan and image topics of a bag (given, or the only one of each type)."""
    from rosbags.rosbag2 import Reader
    try:
        with Reader(str(path)) as reader:
            types = {c.topic: c.msgtype for c in reader.connections}
    except Exception as err:  # noqa: BLE001 - rosbags raises its own kinds for a bad bag
        raise CalibrationError(f'{path}: not a readable rosbag2 bag: {err}') from err

    def pick(given: str, wanted: tuple[str, ...], what: str) -> str:
        if given:
            names = [given, given.lstrip('/'), '/' + given.lstrip('/')]
            for n in names:
                if n in types:
                    if types[n] not in wanted:
                        raise CalibrationError(f'{path}: topic {n} is {types[n]}, not '
                                               f'{" or ".join(wanted)}')
                    return n
            raise CalibrationError(f'{path}: no topic {given}; topics: '
                                   f'{", ".join(sorted(types))}')
        found = sorted(t for t, ty in types.items() if ty in wanted)
        if len(found) != 1:
            raise CalibrationError(f'{path}: {len(found)} {what} topics '
                                   f'({", ".join(found) or "none"}): name one')
        return found[0]

    return Topics(pick(scan, (SCAN_TYPE,), 'LaserScan'), pick(image, IMAGE_TYPES, 'image'))


def messages(path: str | os.PathLike[str], topics: Topics) -> Iterator[tuple[str, Any]]:
    """('scan' or 'image', message) in the bag's order, deserialized one at a time."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import get_typestore, Stores
    store = get_typestore(Stores.ROS2_JAZZY)
    kind = {topics.scan: 'scan', topics.image: 'image'}
    with Reader(str(path)) as reader:
        conns = [c for c in reader.connections if c.topic in kind]
        for conn, _, raw in reader.messages(connections=conns):
            yield kind[conn.topic], store.deserialize_cdr(raw, conn.msgtype)


@dataclass
class StillPose:
    """The board held still: its averaged corners and the scans of that time."""

    start_ns: int
    end_ns: int
    corners: NDArray[np.float64]                      # (M, 2) [px]
    images: int
    scans: list[NDArray[np.float64]] = field(default_factory=list)   # each (N, 2) [m]


def board_corners(image: NDArray[np.uint8], cols: int, rows: int
                  ) -> NDArray[np.float64] | None:
    """Return the board's inner corners [px] as the intrinsic calibration finds them.

    None when not found. ``intrinsics.find_corners`` (ROS's calibrator: its flags, edge
    margin, corner order and subpixel window) on a ``cols`` x ``rows`` board, which detects
    the (longer, shorter) pattern: give ``cols`` >= ``rows`` for the corners to come in the
    order of ``extrinsics.board_object_points(cols, rows, square)``. The square's size does
    not change what the detector sees. Without OpenCV's fast check, which misses far boards.
    """
    return find_corners(image, Board(cols, rows, 1.0), fast_check=False)


def board_poses(stream: Iterator[tuple[str, Any]], cols: int, rows: int, *,
                still_px: float = 1.0, min_still_s: float = 0.5, stride: int = 1,
                corners_of: Callable[[NDArray[np.uint8], int, int],
                                     NDArray[np.float64] | None] = board_corners,
                ) -> list[StillPose]:
    """Split a stream of scans and images into the times the board was held still.

    An image whose corners moved less than ``still_px`` (every corner) since the previous
    image's extends the present pose; a move, or an image without the board, ends it. A pose
    lasting ``min_still_s`` is kept with the scans whose stamps fall inside it (a moving board
    would smear its plane). ``stride``: look at every n-th image only.
    """
    poses: list[StillPose] = []
    scans: list[tuple[int, NDArray[np.float64]]] = []
    current: list[tuple[int, NDArray[np.float64]]] = []
    n_image = 0

    def close(now_ns: int) -> None:
        if len(current) >= 2 and current[-1][0] - current[0][0] >= min_still_s * 1e9:
            start, end = current[0][0], current[-1][0]
            corners = np.mean([c for _, c in current], axis=0)
            poses.append(StillPose(start, end, corners, len(current),
                                   [xy for t, xy in scans if start <= t <= end]))
        current.clear()
        # what came before is of no further use: a new pose starts at this image or later
        scans[:] = [(t, xy) for t, xy in scans if t >= now_ns]

    for kind, msg in stream:
        if kind == 'scan':
            scans.append((stamp_ns(msg), scan_xy(msg)))
            continue
        n_image += 1
        if (n_image - 1) % stride:
            continue
        t_img = stamp_ns(msg)
        corners = corners_of(image_array(msg), cols, rows)
        if corners is None:
            close(t_img)
            continue
        if current and float(np.max(np.linalg.norm(corners - current[-1][1], axis=1))) > still_px:
            close(t_img)
        current.append((t_img, corners))
    close(0)
    return poses
