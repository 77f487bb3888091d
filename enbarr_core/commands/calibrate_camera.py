"""``enbarr calibrate camera [SOURCE]``: camera intrinsics from checkerboard views.

The CS Saucer manual's 4.1 with ROS's ``cameracalibrator``, without a display: views come
from a folder of images, a video file, a bag, or (no SOURCE) the live image topic; a view is
kept when it differs enough from those kept, and the X, Y, size and skew coverage is printed
as it grows (``enbarr_core.vision.intrinsics`` follows camera_calibration's calibrator.py).
Then ``cv2.calibrateCamera``, the reprojection RMS, and the camera_info YAML the camera driver
reads (``--output``); ``--commit`` sends it to the driver's ``camera/set_camera_info``, which
stores it in the driver's ``calibration_file`` (the manual's "commit").
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator
import math
import re
import sys
import time
from typing import Any, TYPE_CHECKING

import numpy as np

from enbarr_core.commands.arguments import check_seconds
from enbarr_core.commands.calibrate import CalibrationAction
from enbarr_core.framework.errors import CalibrationError
from enbarr_core.vision.board import Board
from enbarr_interfaces import topics
from enbarr_core.vision.intrinsics import (
    calibrate, format_progress, Intrinsics, ViewSelector)

if TYPE_CHECKING:
    from enbarr_plugins.camera.calibration import Calibration

#: The manual's board (4.1): 9x7 squares of 40 mm, i.e. 8x6 inner corners.
DEFAULT_SIZE = '8x6'
DEFAULT_SQUARE = 0.040      # [m]
#: A square this large [m] is more likely a slip of the decimal point (the manual's own
#: command line says 0.40 for its 40 mm squares) than a board.
SUSPECT_SQUARE = 0.2
DEFAULT_TOPIC = topics.CAMERA_IMAGE.name


def parse_size(text: str) -> tuple[int, int]:
    """Parse ``8x6`` into (8, 6): inner corners along and across."""
    m = re.fullmatch(r'\s*(\d+)\s*[xX]\s*(\d+)\s*', text)
    if not m or int(m.group(1)) < 2 or int(m.group(2)) < 2:
        raise CalibrationError(f'--size: expected COLSxROWS inner corners, each at least 2 '
                               f"(the manual's board of 9x7 squares is 8x6), got {text!r}")
    return int(m.group(1)), int(m.group(2))


def to_calibration(result: Intrinsics, camera_name: str) -> Any:
    """Return the driver's ``Calibration`` of a result (what its YAML file holds)."""
    from enbarr_plugins.camera.calibration import Calibration

    return Calibration(
        width=result.width, height=result.height, camera_name=camera_name,
        k=tuple(float(x) for x in result.k.ravel()), distortion_model=result.distortion_model,
        d=tuple(float(x) for x in result.d.ravel()),
        r=tuple(float(x) for x in result.r.ravel()),
        p=tuple(float(x) for x in result.p.ravel()))


class CameraCalibration(CalibrationAction):
    """``enbarr calibrate camera``."""

    help = 'camera intrinsics from checkerboard views (images, video, bag or live topic)'
    description = (
        "Calibrate the camera's intrinsics (K, plumb_bob distortion, P) from views of a "
        "checkerboard, the way ROS's cameracalibrator does (CS Saucer manual 4.1). SOURCE is "
        'a folder of images, a video file, or a bag (rosbag2, sensor_msgs/Image or '
        'CompressedImage on --topic); without SOURCE the live --topic is read until the '
        'coverage is complete and --views are kept, or for --duration. --size counts inner '
        'corners: a board of 9x7 squares is 8x6. --square is in metres: 40 mm is 0.040.')

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Declare SOURCE and the options."""
        parser.add_argument('source', nargs='?', metavar='SOURCE',
                            help='folder of images, video file or bag (default: live topic)')
        parser.add_argument('--size', default=DEFAULT_SIZE,
                            help=f'inner corners COLSxROWS (default {DEFAULT_SIZE})')
        parser.add_argument('--square', type=float, default=DEFAULT_SQUARE,
                            help=f'side of a square [m] (default {DEFAULT_SQUARE})')
        parser.add_argument('--topic', default=DEFAULT_TOPIC,
                            help=f'image topic, live or in a bag (default {DEFAULT_TOPIC})')
        parser.add_argument('--duration', type=float, default=120.0,
                            help='live: read at most this long [s] (default 120)')
        parser.add_argument('--views', type=int, default=20,
                            help='live: stop once coverage is complete and this many views '
                            'are kept (default 20)')
        parser.add_argument('-k', '--k-coefficients', type=int, default=2, choices=(1, 2, 3),
                            help='radial distortion coefficients (default 2: k3 = 0, as '
                            'cameracalibrator)')
        parser.add_argument('-o', '--output', metavar='FILE',
                            help="write the camera_info YAML here (the driver's "
                            'calibration_file)')
        parser.add_argument('--camera-name', default='camera',
                            help='camera_name in the YAML (default camera)')
        parser.add_argument('--commit', action='store_true',
                            help="send the result to the driver's set_camera_info service")
        parser.add_argument('--service', default=topics.CAMERA_SET_INFO,
                            help=f'the service --commit calls (default {topics.CAMERA_SET_INFO})')
        parser.add_argument('--timeout', type=float, default=10.0,
                            help='live and --commit: wait this long for the topic or the '
                            'service [s] (default 10)')

    def run(self, args: argparse.Namespace) -> int:
        """Collect views, calibrate, print, write, commit."""
        cols, rows = parse_size(args.size)
        if not (args.square > 0 and math.isfinite(args.square)):
            raise CalibrationError(f'--square must be a positive length in metres, got '
                                   f'{args.square}')
        check_seconds('--duration', args.duration)
        check_seconds('--timeout', args.timeout)
        if args.views < 3:
            raise CalibrationError(f'--views must be at least 3, got {args.views}')
        if args.square >= SUSPECT_SQUARE:
            print(f'enbarr calibrate: warning: --square {args.square:g} m is a square of '
                  f'{args.square * 100:g} cm; a 40 mm square is 0.040', file=sys.stderr)
        board = Board(cols, rows, args.square)
        if args.source is None:
            selector = collect_live(board, args.topic, args.duration, args.timeout, args.views)
            where = args.topic
        else:
            from enbarr_core.vision.sources import open_source
            selector = collect(board, open_source(args.source, args.topic))
            where = args.source
        if selector is None or not selector.views:
            seen = selector.seen if selector else 0
            raise CalibrationError(
                f'{where}: no {cols}x{rows} board found in any of {seen} images (--size counts '
                'inner corners: a board of 9x7 squares is 8x6)')
        if not selector.good_enough:
            print(f'enbarr calibrate: warning: coverage incomplete '
                  f'({format_progress(selector.progress())}): show the board in more places, '
                  'sizes and tilts for a better calibration', file=sys.stderr)
        result = calibrate(selector.views, board, selector.size, args.k_coefficients)
        cal = to_calibration(result, args.camera_name)
        report(result, selector)
        from enbarr_plugins.camera.calibration import format_calibration, save_calibration
        if args.output:
            try:
                save_calibration(cal, args.output)
            except OSError as err:
                raise CalibrationError(f'{args.output}: cannot write: '
                                       f'{err.strerror or err}') from err
            print(f'wrote {args.output}')
        else:
            print(format_calibration(cal), end='')
        if args.commit:
            status = commit(cal, args.service, args.timeout)
            print(f'committed to {args.service}: {status or "ok"}')
        return 0


def collect(board: Board, frames: Iterator[tuple[str, np.ndarray]],
            selector: ViewSelector | None = None) -> ViewSelector | None:
    """Offer every frame to a selector (made from the first frame's size); print progress."""
    for label, image in frames:
        if selector is None:
            selector = ViewSelector(board, (image.shape[1], image.shape[0]))
        view = selector.offer(image, label)
        if view is not None:
            print_view(selector, view.label, view.params)
    return selector


def print_view(selector: ViewSelector, label: str, params: tuple[float, ...]) -> None:
    """One line per kept view, as cameracalibrator prints its samples, with the coverage."""
    x, y, size, skew = params
    print(f'view {len(selector.views)} kept ({label}): X {x:.3f} Y {y:.3f} size {size:.3f} '
          f'skew {skew:.3f} | coverage {format_progress(selector.progress())}', flush=True)


def report(result: Intrinsics, selector: ViewSelector) -> None:
    """Print the result: views, RMS, K, D, P."""
    k = result.k
    print(f'calibrated from {result.views} views ({selector.detected} of {selector.seen} '
          f'images showed the board): reprojection RMS {result.rms:.3f} px')
    print(f'fx {k[0, 0]:.3f}  fy {k[1, 1]:.3f}  cx {k[0, 2]:.3f}  cy {k[1, 2]:.3f} [px]')
    print('D (k1 k2 p1 p2 k3) = ' + ' '.join(f'{x:.6f}' for x in result.d))
    print('P = ' + ' '.join(f'{x:.3f}' for x in result.p.ravel()))


def collect_live(board: Board, topic: str, duration: float, timeout: float,
                 views: int) -> ViewSelector | None:
    """Read ``topic`` until coverage is complete with ``views`` kept, or ``duration`` passes.

    The latest frame is processed when the last is done (older ones are dropped, as
    cameracalibrator's queue of one). No frame within ``timeout`` is an error naming the
    image topics the graph has. Ctrl-C ends the collection and calibrates what was kept.
    """
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions
    from sensor_msgs.msg import Image

    from enbarr_core.vision.sources import decode_image

    ctx = Context()
    rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node('enbarr_calibrate_camera', context=ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    latest: list[Any] = []
    node.create_subscription(Image, topic, lambda m: latest.__setitem__(slice(None), [m]),
                             topics.CAMERA_IMAGE.qos)
    selector: ViewSelector | None = None
    frames = 0
    start = time.monotonic()
    try:
        while time.monotonic() - start < duration:
            executor.spin_once(timeout_sec=0.05)
            if not latest:
                if frames == 0 and time.monotonic() - start > timeout:
                    names = sorted(n for n, types in node.get_topic_names_and_types()
                                   if 'sensor_msgs/msg/Image' in types)
                    raise CalibrationError(f'{topic}: no image in {timeout:g} s; image topics '
                                           f'seen: {", ".join(names) or "none"}')
                continue
            msg = latest.pop()
            frames += 1
            stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            selector = collect(board, iter([(f'{topic} at {stamp:.3f} s',
                                             decode_image(msg, topic))]), selector)
            if selector is not None and selector.good_enough and len(selector.views) >= views:
                break
    except KeyboardInterrupt:
        print('stopped: calibrating with the views kept', file=sys.stderr)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    return selector


def commit(cal: Calibration, service: str, timeout: float) -> str:
    """Send ``cal`` to a ``SetCameraInfo`` service; its status message. Refusal is an error."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions
    from sensor_msgs.srv import SetCameraInfo

    from enbarr_plugins.camera.common import camera_info

    ctx = Context()
    rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node('enbarr_calibrate_commit', context=ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    try:
        client = node.create_client(SetCameraInfo, service)
        if not client.wait_for_service(timeout_sec=timeout):
            raise CalibrationError(f'{service}: no such service in {timeout:g} s (is the camera '
                                   'driver running, in this ROS_DOMAIN_ID?)')
        request = SetCameraInfo.Request()
        request.camera_info = camera_info(cal, cal.width, cal.height)
        future = client.call_async(request)
        executor.spin_until_future_complete(future, timeout_sec=timeout)
        if not future.done() or future.result() is None:
            raise CalibrationError(f'{service}: no answer in {timeout:g} s')
        response = future.result()
        if not response.success:
            raise CalibrationError(f'{service} refused: {response.status_message}')
        return str(response.status_message)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
