"""``enbarr calibrate lidar`` and ``enbarr calibrate reproject``: camera to 2D lidar (manual 4.2).

``lidar`` solves T_optical_laser (``enbarr_core.vision.extrinsics``) by one of two methods and
writes the camera's frame into the profile:

- ``--method pnp --pairs PAIRS.csv``: the manual's marks, one line per mark:
  ``x,y,u,v`` (the lidar point [m] in the laser frame, the pixel where the mark is seen);
- ``--method planes --bag BAG --board 8x6 --square 0.04``: the checkerboard held still in
  poses the camera and the lidar both see (Zhang and Pless 2004).

``reproject`` draws a bag's scans onto its images through the profile's frame tree (the
manual's reprojection launch): a PNG of one image, or a video of all.

Run standalone as ``python -m enbarr_core.commands.calibrate_lidar lidar|reproject ...``;
the ``calibrate`` command hangs ``add_*_arguments`` and ``run_*`` under its own subcommands.
"""

from __future__ import annotations

import argparse
import csv
from collections.abc import Sequence
from datetime import datetime, timezone
from pathlib import Path
import sys
from typing import TYPE_CHECKING

import numpy as np

from enbarr_core.framework.errors import CalibrationError, EnbarrError

if TYPE_CHECKING:
    from enbarr_core.framework.frames import Transform
    from enbarr_core.vision.extrinsics import CameraModel, ExtrinsicsResult

LIDAR_HELP = 'solve where the lidar sits in the camera frame and write it into the profile'
REPROJECT_HELP = 'draw the lidar scans onto the camera images (PNG or video)'
#: The RPLidar A1's range noise, CS Saucer manual Table 1.1 (one standard deviation).
A1_LIMITS = (3.0, 5.0)
A1_FRACTIONS = (0.01, 0.02, 0.025)


# -- lidar ------------------------------------------------------------------------------------
def add_lidar_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare the options of ``calibrate lidar``."""
    parser.add_argument('--method', choices=('pnp', 'planes'), required=True,
                        help='pnp: marks seen by both (manual 4.2; --pairs); planes: a '
                             'checkerboard in several poses (--bag, --board, --square)')
    parser.add_argument('--profile', required=True,
                        help='the vessel profile whose frame tree holds laser and camera '
                             '(start and target of the calibration)')
    parser.add_argument('--camera-info', required=True, metavar='YAML',
                        help='the camera intrinsics (camera_info YAML, manual 4.1)')
    parser.add_argument('--pairs', metavar='CSV',
                        help='pnp: lines x,y,u,v (lidar point [m], pixel); a header line and '
                             '# comments are skipped')
    parser.add_argument('--bag', help='planes: a bag with a LaserScan and an image topic')
    parser.add_argument('--scan-topic', default='', help='default: the only LaserScan topic')
    parser.add_argument('--image-topic', default='',
                        help='default: the only Image or CompressedImage topic')
    parser.add_argument('--board', default='8x6', metavar='COLSxROWS',
                        help="inner corners of the checkerboard (default 8x6: the manual's "
                             '9 x 7 squares)')
    parser.add_argument('--square', type=float, default=0.04,
                        help="square side [m] (default 0.04, the manual's)")
    parser.add_argument('--still-px', type=float, default=1.0,
                        help='planes: the board counts as held still while no corner moves '
                             'more than this between images [px]')
    parser.add_argument('--min-still', type=float, default=0.5,
                        help='planes: a pose must be held this long [s]')
    parser.add_argument('--tolerance', type=float, default=0.1,
                        help='planes: scan points within this of the board as the profile '
                             "places it are the board's [m]")
    parser.add_argument('--stride', type=int, default=1, help='planes: every n-th image')
    parser.add_argument('--outlier-px', type=float, default=8.0,
                        help='pnp: drop a pair off by more than this [px]')
    parser.add_argument('--frame', default='camera_link',
                        help='the frame whose pose is written (default camera_link; its '
                             'optical frame keeps its fixed rotation)')
    parser.add_argument('--optical-frame', default='camera_optical_frame')
    parser.add_argument('--laser-frame', default='laser')
    out = parser.add_mutually_exclusive_group()
    out.add_argument('--write', action='store_true',
                     help='write the frame into the profile file that declares it (the '
                          'rest of the file, comments included, is kept)')
    out.add_argument('--fragment', metavar='YAML',
                     help='write the frame into this include-only file instead')


def run_lidar(args: argparse.Namespace) -> int:
    """Solve, print the result, write it when asked; exit code."""
    from enbarr_core.bringup.frame_write import write_fragment, write_frame
    from enbarr_core.bringup.profile import load_profile
    from enbarr_core.vision import extrinsics as E

    profile = load_profile(args.profile, allow_fragment=True)
    tree = profile.frames
    camera = load_camera(args.camera_info)
    guess = E.optical_laser(tree, args.optical_frame, args.laser_frame)
    if args.method == 'pnp':
        if not args.pairs:
            raise CalibrationError('--method pnp needs --pairs CSV')
        xy, uv = read_pairs(args.pairs)
        result = E.solve_pnp(xy, uv, camera, outlier_px=args.outlier_px)
        dropped = np.flatnonzero(~result.used)
        if len(dropped):
            print(f'dropped as outliers (line order, from 0): {dropped.tolist()}')
    else:
        if not args.bag:
            raise CalibrationError('--method planes needs --bag BAG')
        result = _solve_bag(args, camera, guess)
    print(result.summary())
    pose = E.frame_pose_from(tree, result.transform, frame=args.frame,
                             optical=args.optical_frame, laser=args.laser_frame)
    parent = tree.frame(args.frame).parent
    rpy = np.degrees(pose.rpy)
    print(f'{args.frame} in {parent}: xyz [m] {_fmt(pose.translation)}, rpy [deg] {_fmt(rpy)}')
    note = (f'calibrated {datetime.now(timezone.utc):%Y-%m-%d} (enbarr calibrate lidar, '
            f'{result.method}, rms {result.rms:.3g} {result.unit})')
    if args.write:
        written = write_frame(args.profile, args.frame, pose, note=note)
        print(f'wrote frames.{args.frame} in {written.path}')
    elif args.fragment:
        # merged key by key over the entry: the rotation in the form the profile has it
        quaternion = f'frames.{args.frame}.quaternion' in profile.origins
        assert parent is not None
        write_fragment(args.fragment, args.frame, parent, pose, note=note,
                       rotation_key='quaternion' if quaternion else 'rpy')
        print(f'wrote {args.fragment}: add it last to include: in {args.profile}')
    else:
        print('(not written: --write or --fragment YAML)')
    return 0


def _fmt(v: Sequence[float] | np.ndarray) -> str:
    return '[' + ', '.join(f'{x:.4f}' for x in np.asarray(v, dtype=float)) + ']'


def load_camera(path: str) -> CameraModel:
    """Read a camera_info YAML (manual 4.1) into the extrinsics solvers' camera model.

    CalibrationError naming the file when it cannot be read.
    """
    from enbarr_core.vision.extrinsics import CameraModel
    from enbarr_plugins.camera.calibration import load_calibration
    try:
        cal = load_calibration(path)
    except ValueError as err:
        raise CalibrationError(str(err)) from err
    if cal.distortion_model not in ('plumb_bob', 'rational_polynomial'):
        raise CalibrationError(f"{path}: distortion_model {cal.distortion_model!r}: OpenCV's "
                               'pinhole model reads plumb_bob and rational_polynomial')
    return CameraModel.of(cal.k, cal.d, cal.width, cal.height, cal.distortion_model)


def read_pairs(path: str) -> tuple[np.ndarray, np.ndarray]:
    """Read ``x,y,u,v`` lines (a header and ``#`` comments skipped); error names the line."""
    rows: list[list[float]] = []
    try:
        with open(path, newline='') as f:
            for n, line in enumerate(csv.reader(f), start=1):
                if not line or line[0].lstrip().startswith('#'):
                    continue
                try:
                    values = [float(v) for v in line]
                except ValueError:
                    if not rows and n == 1:
                        continue   # the header
                    raise CalibrationError(f'{path}:{n}: expected numbers x,y,u,v, got '
                                           f'{",".join(line)!r}') from None
                if len(values) != 4 or not np.all(np.isfinite(values)):
                    raise CalibrationError(f'{path}:{n}: expected 4 finite numbers x,y,u,v')
                rows.append(values)
    except OSError as err:
        raise CalibrationError(f'{path}: cannot read: {err.strerror or err}') from err
    a = np.array(rows, dtype=float).reshape(-1, 4)
    return a[:, :2], a[:, 2:]


def _board_size(text: str) -> tuple[int, int]:
    try:
        cols, rows = (int(v) for v in text.lower().split('x'))
    except ValueError:
        raise CalibrationError(f'--board {text!r}: expected COLSxROWS inner corners, e.g. '
                               '8x6') from None
    # the detector (ROS's calibrator's) finds the longer side first: so do the board points
    return max(cols, rows), min(cols, rows)


def _solve_bag(args: argparse.Namespace, camera: CameraModel,
               guess: Transform) -> ExtrinsicsResult:
    from enbarr_core.perception.scan_geometry import RangeNoise
    from enbarr_core.vision import extrinsics as E
    from enbarr_core.vision import recorded

    cols, rows = _board_size(args.board)
    obj = E.board_object_points(cols, rows, args.square)
    topics = recorded.bag_topics(args.bag, args.scan_topic, args.image_topic)
    poses = recorded.board_poses(recorded.messages(args.bag, topics), cols, rows,
                                 still_px=args.still_px, min_still_s=args.min_still,
                                 stride=args.stride)
    # the board's squares in its frame; the paper's margin is within the tolerance
    extent = (-args.square, cols * args.square, -args.square, rows * args.square)
    planes, points = [], []
    for i, pose in enumerate(poses):
        plane = E.board_plane(pose.corners, obj, camera)
        on = [xy[E.select_board_points(xy, plane, guess, extent,
                                       tolerance=args.tolerance)] for xy in pose.scans]
        pts = np.concatenate(on) if on else np.zeros((0, 2))
        print(f'pose {i}: {pose.images} images over '
              f'{(pose.end_ns - pose.start_ns) / 1e9:.1f} s, {len(pose.scans)} scans, '
              f'{len(pts)} points on the board, corners rms {plane.rms_px:.2f} px')
        if len(pts) < E.MIN_POINTS_PER_BOARD:
            print(f'pose {i}: left out (the scan plane does not cross the board)')
            continue
        planes.append(plane)
        points.append(pts)
    if not poses:
        raise CalibrationError(f'{args.bag}: the board ({args.board}) was never seen held '
                               f'still for {args.min_still} s')
    initial = guess if len(planes) < E.MIN_PLANES_LINEAR else None
    return E.solve_planes(planes, points, initial=initial, camera=camera,
                          range_noise=RangeNoise(A1_LIMITS, A1_FRACTIONS))


# -- reproject ----------------------------------------------------------------------------------
def add_reproject_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare the options of ``calibrate reproject``."""
    parser.add_argument('--bag', required=True, help='a bag with a LaserScan and images')
    parser.add_argument('--profile', required=True, help='the profile whose frame tree to use')
    parser.add_argument('--camera-info', required=True, metavar='YAML')
    parser.add_argument('--output', required=True,
                        help='a .png (one image: --index) or a video (.mp4, .avi)')
    parser.add_argument('--index', type=int, default=0,
                        help='PNG: which image of the bag (from 0; negative from the end)')
    parser.add_argument('--scan-topic', default='')
    parser.add_argument('--image-topic', default='')
    parser.add_argument('--optical-frame', default='camera_optical_frame')
    parser.add_argument('--laser-frame', default='laser')
    parser.add_argument('--fps', type=float, default=10.0, help='video frame rate')


def run_reproject(args: argparse.Namespace) -> int:
    """Draw each image's latest scan onto it; write the PNG or the video; exit code."""
    import cv2

    from enbarr_core.bringup.profile import load_profile
    from enbarr_core.vision import extrinsics as E
    from enbarr_core.vision import recorded

    tree = load_profile(args.profile, allow_fragment=True).frames
    transform = E.optical_laser(tree, args.optical_frame, args.laser_frame)
    camera = load_camera(args.camera_info)
    topics = recorded.bag_topics(args.bag, args.scan_topic, args.image_topic)
    out = Path(args.output)
    video = out.suffix.lower() in ('.mp4', '.avi')
    if not video and out.suffix.lower() != '.png':
        raise CalibrationError(f'--output {out}: expected .png, .mp4 or .avi')
    last_scan: np.ndarray | None = None
    frames: list[np.ndarray] = []
    writer = None
    count = 0
    for kind, msg in recorded.messages(args.bag, topics):
        if kind == 'scan':
            last_scan = recorded.scan_xy(msg)
            continue
        img = recorded.image_array(msg)
        if last_scan is not None:
            draw_scan(img, last_scan, transform, camera)
        count += 1
        if video:
            if writer is None:
                fourcc = cv2.VideoWriter.fourcc(*('mp4v' if out.suffix == '.mp4' else 'MJPG'))
                writer = cv2.VideoWriter(str(out), fourcc, args.fps,
                                         (img.shape[1], img.shape[0]))
                if not writer.isOpened():
                    raise CalibrationError(f'{out}: OpenCV cannot write this video here; '
                                           'try .avi')
            writer.write(img)
        elif args.index >= 0 and count - 1 == args.index:
            frames = [img]
            break
        elif args.index < 0:
            frames = (frames + [img])[args.index:]
    if writer is not None:
        writer.release()
        print(f'wrote {out}: {count} images')
        return 0
    if not frames or (args.index < 0 and len(frames) < -args.index):
        raise CalibrationError(f'{args.bag}: no image {args.index} ({count} images)')
    if not cv2.imwrite(str(out), frames[0]):
        raise CalibrationError(f'{out}: cannot write')
    print(f'wrote {out}')
    return 0


def draw_scan(image: np.ndarray, laser_xy: np.ndarray, transform: Transform,
              camera: CameraModel) -> int:
    """Draw scan points onto ``image`` (BGR, in place), coloured by range; return how many."""
    import cv2

    from enbarr_core.vision.extrinsics import project_scan
    px, ok = project_scan(laser_xy, transform, camera)
    r = np.linalg.norm(laser_xy, axis=1)
    # near red, far blue over 0.5 to 6 m: depth is what a misaligned scan gets wrong
    hue = np.clip((r - 0.5) / 5.5, 0.0, 1.0) * 120
    for (u, v), h, good in zip(px, hue, ok):
        if good:
            bgr = cv2.cvtColor(np.array([[[h, 255, 255]]], dtype=np.uint8),
                               cv2.COLOR_HSV2BGR)[0, 0]
            cv2.circle(image, (int(round(u)), int(round(v))), 2,
                       tuple(int(c) for c in bgr), -1)
    return int(ok.sum())


# -- standalone -------------------------------------------------------------------------------
def main(argv: Sequence[str] | None = None) -> int:
    """``python -m enbarr_core.commands.calibrate_lidar lidar|reproject ...``."""
    parser = argparse.ArgumentParser(prog='calibrate_lidar', description=__doc__.split('\n')[0])
    sub = parser.add_subparsers(dest='action', required=True)
    add_lidar_arguments(sub.add_parser('lidar', help=LIDAR_HELP))
    add_reproject_arguments(sub.add_parser('reproject', help=REPROJECT_HELP))
    args = parser.parse_args(argv)
    try:
        return run_lidar(args) if args.action == 'lidar' else run_reproject(args)
    except EnbarrError as err:
        print(f'calibrate {args.action}: error: {err}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
