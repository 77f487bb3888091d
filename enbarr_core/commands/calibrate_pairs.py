"""``enbarr calibrate pairs``: the manual's mark pairs (4.2) from a bag or the live topics.

Writes the CSV that ``enbarr calibrate lidar --method pnp --pairs`` reads: a header line
``x,y,u,v``, then one line per pose of the mark held still (the lidar point [m] in the laser
frame, the pixel), each after a ``#`` comment saying where it came from. The algorithms are
``enbarr_core.vision.marks``; here the options, the bag or subscription, and the picking.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
import os
import sys
import time
from typing import Any, TYPE_CHECKING

import numpy as np

from enbarr_core.framework.errors import CalibrationError

if TYPE_CHECKING:
    from enbarr_core.vision.classical import ColourClass
    from enbarr_core.vision.marks import MarkPose, PairCollector, Pixel

PAIRS_HELP = ('collect the mark pairs (lidar point, pixel) of manual 4.2 from a bag or live '
              'into the CSV of calibrate lidar --method pnp')
PAIRS_DESCRIPTION = (
    "Hold a mark (a pole, or a post with a band of tape centred on the lidar's height) still "
    'at 10 to 20 places the camera sees, a second or two each. Each place the lidar sees it '
    "still (--min-still, --tolerance) gives one pair: the mark's centre in the scans, and its "
    'pixel: the centroid of its colour (--pick colour --colour NAME, headless) or a click in a '
    'window (--pick click, needs a display). Restrict where the mark may be with --region so '
    'walls and buoys are not taken. Then: enbarr calibrate lidar --method pnp --pairs CSV.')


def add_pairs_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare the options of ``calibrate pairs``."""
    src = parser.add_mutually_exclusive_group(required=True)
    src.add_argument('--bag', help='read a bag with a LaserScan and an image topic')
    src.add_argument('--live', action='store_true',
                     help='subscribe to the live scan and image topics for --seconds')
    parser.add_argument('--seconds', type=float, default=60.0,
                        help='--live: how long to listen [s] (default 60; Ctrl-C ends early)')
    parser.add_argument('--count', type=int, default=0,
                        help='--live: stop listening once this many places were held still '
                             '(default 0: listen for --seconds)')
    parser.add_argument('-o', '--output', required=True, metavar='CSV',
                        help='the pairs file to write (x,y,u,v)')
    parser.add_argument('--scan-topic', default='',
                        help="default: the bag's only LaserScan topic; live: scan")
    parser.add_argument('--image-topic', default='',
                        help="default: the bag's only image topic; live: "
                             'camera/image_raw/compressed (a name ending in /compressed is '
                             'a CompressedImage, any other an Image)')
    parser.add_argument('--pick', choices=('colour', 'click'), default='colour',
                        help="colour: the centroid of the mark's colour in the images "
                             '(headless); click: click the mark in a window (needs a display)')
    parser.add_argument('--colour', default='',
                        help='--pick colour: a named colour (red, green, yellow, orange: the '
                             "classical detector's boxes)")
    parser.add_argument('--hue', default='', metavar='LO,HI',
                        help='--pick colour: an OpenCV hue range 0..179 instead (LO > HI '
                             'wraps through 0, as red)')
    parser.add_argument('--min-saturation', type=int, default=100,
                        help='--hue: the least saturation 0..255 (default 100)')
    parser.add_argument('--min-value', type=int, default=50,
                        help='--hue: the least value 0..255 (default 50)')
    parser.add_argument('--min-area', type=float, default=30.0,
                        help='--pick colour: the least blob area [px] (default 30)')
    parser.add_argument('--region', default='', metavar='XMIN,XMAX,YMIN,YMAX',
                        help='where the mark may be [m] in the laser frame (x ahead, y left)')
    parser.add_argument('--max-range', type=float, default=5.0,
                        help='the mark is nearer than this [m] (default 5)')
    parser.add_argument('--max-width', type=float, default=0.3,
                        help='a cluster wider than this [m] is not the mark (default 0.3)')
    parser.add_argument('--mark-radius', type=float, default=0.0,
                        help="the mark's radius [m]: its centre is fitted behind the points "
                             'the lidar sees (default 0: their mean)')
    parser.add_argument('--tolerance', type=float, default=0.08,
                        help='the mark is still while within this of its mean [m] '
                             "(default 0.08: the A1's noise at 3 m moves a thin mark's "
                             'points by a few cm)')
    parser.add_argument('--min-still', type=float, default=1.0,
                        help='a place counts when the mark is held still this long [s] '
                             '(default 1)')
    parser.add_argument('--profile', default='',
                        help="--pick click: the profile whose frame tree marks the lidar's "
                             'guess on the image (with --camera-info)')
    parser.add_argument('--camera-info', default='', metavar='YAML',
                        help='--pick click: the camera intrinsics, for the guess')
    parser.add_argument('--optical-frame', default='camera_optical_frame')
    parser.add_argument('--laser-frame', default='laser')


def run_pairs(args: argparse.Namespace) -> int:
    """Collect, pick, write the CSV; exit code."""
    from enbarr_core.vision import marks
    from enbarr_core.vision.extrinsics import MIN_PNP_PAIRS

    settings = marks.MarkSettings(region=_region(args.region), max_range=args.max_range,
                                  max_width=args.max_width, radius=args.mark_radius,
                                  tolerance=args.tolerance, min_still=args.min_still)
    settings.validate()
    if args.pick == 'colour':
        colour = _colour(args)
        min_area = args.min_area

        def pixel_of(image: np.ndarray) -> Pixel | None:
            return marks.blob_centre(image, colour, min_area=min_area)
        collector = marks.PairCollector(settings, pixel_of)
    else:
        _check_display()
        collector = marks.PairCollector(settings, None)
    if args.bag:
        source = args.bag
        _feed_bag(collector, args.bag, args.scan_topic, args.image_topic)
    else:
        source = 'live'
        _feed_live(collector, args.scan_topic or 'scan',
                   args.image_topic or 'camera/image_raw/compressed', args.seconds, args.count)
    poses = collector.finish()
    print(f'{collector.scans} scans ({collector.with_mark} with one mark candidate, '
          f'{collector.ambiguous} with several), {collector.images} images: '
          f'{len(poses)} places held still for {settings.min_still:g} s')
    if not poses:
        hint = (f'; {collector.ambiguous} scans had several candidates: narrow --region'
                if collector.ambiguous else '')
        raise CalibrationError(f'{source}: the mark was never held still for '
                               f'{settings.min_still:g} s within {settings.tolerance:g} m '
                               f'({collector.with_mark} of {collector.scans} scans showed one '
                               f'mark candidate{hint})')
    if args.pick == 'colour':
        marks.colour_pixels(poses)
        if not any(p.pixel for p in poses):
            images = sum(p.images for p in poses)
            raise CalibrationError(f'{source}: no blob of the colour in the {images} images of '
                                   'the still places: check --colour or --hue (OpenCV HSV), '
                                   '--min-area')
    else:
        _click(poses, args)
    for i, p in enumerate(poses):
        xy = f'({p.centre[0]:.3f}, {p.centre[1]:.3f}) m'
        if p.pixel is None:
            why = ('no image' if not p.images
                   else 'skipped' if args.pick == 'click' else 'no blob in its images')
            print(f'place {i}: {xy}: left out ({why})')
        else:
            print(f'place {i}: {xy} over {p.scans} scans, pixel ({p.pixel[0]:.1f}, '
                  f'{p.pixel[1]:.1f}) from {len(p.pixels) or 1} of {p.images} images')
    pairs = [p for p in poses if p.pixel is not None]
    if len(pairs) < MIN_PNP_PAIRS:
        raise CalibrationError(
            f'{len(pairs)} pairs found ({len(poses)} places held still): PnP needs at least '
            f'{MIN_PNP_PAIRS} (the manual suggests 10 to 20); hold the mark still at more '
            'places')
    write_pairs(args.output, pairs, source, args.pick)
    print(f'wrote {args.output}: {len(pairs)} pairs')
    return 0


def write_pairs(path: str, pairs: Sequence[MarkPose], source: str, pick: str) -> None:
    """Write the CSV ``read_pairs`` reads: a header, a comment and a line per pair."""
    # the header first: read_pairs takes a non-numeric line as the header only there
    lines = ['x,y,u,v', f'# enbarr calibrate pairs from {source}, pixels by {pick}']
    for i, p in enumerate(pairs):
        assert p.pixel is not None
        lines.append(f'# place {i}: {p.start_ns / 1e9:.3f} to {p.end_ns / 1e9:.3f} s, '
                     f'{p.scans} scans, {len(p.pixels) or 1} of {p.images} images')
        lines.append(f'{p.centre[0]:.5f},{p.centre[1]:.5f},{p.pixel[0]:.3f},{p.pixel[1]:.3f}')
    try:
        with open(path, 'w') as f:
            f.write('\n'.join(lines) + '\n')
    except OSError as err:
        raise CalibrationError(f'{path}: cannot write: {err.strerror or err}') from err


def _region(text: str) -> tuple[float, float, float, float] | None:
    if not text:
        return None
    try:
        x0, x1, y0, y1 = (float(v) for v in text.split(','))
    except ValueError:
        raise CalibrationError(f'--region {text!r}: expected XMIN,XMAX,YMIN,YMAX [m] in the '
                               'laser frame, e.g. 0.5,4,-2,2') from None
    return x0, x1, y0, y1


def _colour(args: argparse.Namespace) -> ColourClass:
    from enbarr_core.vision.classical import ColourClass
    from enbarr_core.vision.marks import COLOURS
    if args.colour and args.hue:
        raise CalibrationError('--colour or --hue, not both')
    if args.colour:
        if args.colour not in COLOURS:
            raise CalibrationError(f'--colour {args.colour!r}: one of {", ".join(COLOURS)}, '
                                   'or --hue LO,HI')
        return COLOURS[args.colour]
    if not args.hue:
        raise CalibrationError("--pick colour needs the mark's colour: --colour NAME or "
                               '--hue LO,HI')
    try:
        lo, hi = (int(v) for v in args.hue.split(','))
    except ValueError:
        raise CalibrationError(f'--hue {args.hue!r}: expected LO,HI (OpenCV hue 0..179)'
                               ) from None
    c = ColourClass('mark', (lo, args.min_saturation, args.min_value), (hi, 255, 255))
    try:
        c.validate()
    except ValueError as err:
        raise CalibrationError(f'--hue/--min-saturation/--min-value: {err}') from err
    return c


def _check_display() -> None:
    """Refuse clicking where no window can open, before the bag is read."""
    if not (os.environ.get('DISPLAY') or os.environ.get('WAYLAND_DISPLAY')):
        raise CalibrationError('--pick click needs a display (no $DISPLAY here): use --pick '
                               "colour with the mark's colour, or write the CSV x,y,u,v by "
                               'hand (docs/calibration_lidar.md)')
    import matplotlib.pyplot as plt
    if plt.get_backend().lower() == 'agg':
        raise CalibrationError('--pick click: matplotlib has no interactive backend here '
                               '(install python3-tk, or use --pick colour)')


def _feed_bag(collector: PairCollector, bag: str, scan: str, image: str) -> None:
    from enbarr_core.vision import recorded
    topics = recorded.bag_topics(bag, scan, image)
    print(f'{bag}: scans {topics.scan}, images {topics.image}')
    for kind, msg in recorded.messages(bag, topics):
        feed(collector, kind, msg)


def feed(collector: PairCollector, kind: str, msg: Any) -> None:
    """Hand one message (rosbags' or rclpy's: the same fields) to the collector."""
    from enbarr_core.vision import recorded
    if kind == 'scan':
        collector.add_scan(recorded.stamp_ns(msg), msg.ranges, float(msg.angle_min),
                           float(msg.angle_increment))
    else:
        collector.add_image(recorded.stamp_ns(msg), recorded.image_array(msg))


def _feed_live(collector: PairCollector, scan_topic: str, image_topic: str,
               seconds: float, count: int = 0) -> None:
    """Subscribe to both topics for ``seconds``, or until ``count`` places were held still.

    Ctrl-C ends early; no message on a topic is an error naming the topics of its type.
    """
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions
    from sensor_msgs.msg import CompressedImage, Image, LaserScan

    from enbarr_interfaces import topics

    image_type = CompressedImage if image_topic.endswith('/compressed') else Image
    ctx = Context()
    rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node('enbarr_calibrate_pairs', context=ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    node.create_subscription(LaserScan, scan_topic, lambda m: feed(collector, 'scan', m),
                             topics.SCAN.qos)
    node.create_subscription(image_type, image_topic, lambda m: feed(collector, 'image', m),
                             topics.CAMERA_IMAGE.qos)
    print(f'listening to {scan_topic} and {image_topic} for {seconds:g} s')
    start = time.monotonic()
    try:
        while time.monotonic() - start < seconds:
            executor.spin_once(timeout_sec=0.05)
            if count and collector.places >= count:
                break
        seen = dict(node.get_topic_names_and_types())
    except KeyboardInterrupt:
        print('stopped: pairing what was collected', file=sys.stderr)
        seen = {}
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    for n, what, kinds in ((collector.scans, scan_topic, ('sensor_msgs/msg/LaserScan',)),
                           (collector.images, image_topic,
                            ('sensor_msgs/msg/Image', 'sensor_msgs/msg/CompressedImage'))):
        if n == 0:
            names = sorted(t for t, ty in seen.items() if set(ty) & set(kinds))
            raise CalibrationError(f'{what}: no message in {seconds:g} s; such topics seen: '
                                   f'{", ".join(names) or "none"}')


def _click(poses: Sequence[MarkPose], args: argparse.Namespace) -> None:
    """Show each place's image, the guess marked; take the click, a skip or the end."""
    from enbarr_core.vision import marks
    project = _guess_projector(args)
    for i, p in enumerate(poses):
        if p.image is None:
            continue
        guess = project(p.centre) if project else None
        title = f'place {i} of {len(poses)}: lidar ({p.centre[0]:.2f}, {p.centre[1]:.2f}) m'
        picker = marks.show_for_click(p.image, title, guess)
        p.pixel = picker.pixel
        if picker.quit:
            break


def _guess_projector(args: argparse.Namespace) -> Any:
    """Laser point -> pixel through the profile's frame tree, or None without one."""
    if not (args.profile and args.camera_info):
        return None
    from enbarr_core.bringup.profile import load_profile
    from enbarr_core.commands.calibrate_lidar import load_camera
    from enbarr_core.vision.extrinsics import optical_laser, project_scan

    tree = load_profile(args.profile, allow_fragment=True).frames
    transform = optical_laser(tree, args.optical_frame, args.laser_frame)
    camera = load_camera(args.camera_info)

    def project(xy: np.ndarray) -> Pixel | None:
        px, ok = project_scan(np.asarray(xy, dtype=float).reshape(1, 2), transform, camera)
        return (float(px[0, 0]), float(px[0, 1])) if ok[0] else None
    return project
