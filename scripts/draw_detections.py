"""The pictures of docs/vision.md from a bag: a frame with the detector's boxes drawn on it.

    python3 scripts/draw_detections.py BAG OUT.png [--index N] [--camera-info OUT.yaml]

Reads a bag recorded from a profile with the camera and the detector
(``enbarr bringup --profile saucer_detector_sim --duration 15 --output BAG`` records the JPEG,
``detections`` and ``camera/camera_info``), takes the N-th ``detections`` message that has a
box, finds the JPEG of the same stamp and draws the boxes with the detector's own
``annotate`` (what ``detections/image`` shows live). ``--camera-info`` also writes the bag's
first camera_info as a ROS camera_info YAML, which ``enbarr calibrate reproject
--camera-info`` takes (the simulated camera publishes its true lens).
"""

from __future__ import annotations

import argparse
import sys

import cv2

from enbarr_core.recording.bag import read_bag
from enbarr_core.vision.detection import Detection
from enbarr_core.vision.detector_node import annotate, SPECS
from enbarr_core.vision.recorded import image_array, stamp_ns
from enbarr_interfaces.detections import from_cloud
from enbarr_plugins.camera.calibration import calibration_of, save_calibration


def main(argv: list[str] | None = None) -> int:
    """Write the picture (and the camera_info YAML); exit code 1 when the bag lacks them."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('bag')
    parser.add_argument('output', help='the PNG to write')
    parser.add_argument('--index', type=int, default=0,
                        help='which detections message with a box (from 0)')
    parser.add_argument('--camera-info', default='', metavar='YAML')
    args = parser.parse_args(argv)
    msgs = read_bag(args.bag)
    images = {stamp_ns(m): m for _, m in msgs.get('/camera/image_raw/compressed', [])}
    boxed = [c for _, c in msgs.get('/detections', []) if len(from_cloud(c))]
    if args.index >= len(boxed):
        print(f'{args.bag}: {len(boxed)} detections messages with a box', file=sys.stderr)
        return 1
    cloud = boxed[args.index]
    image = images.get(stamp_ns(cloud))
    if image is None:
        print(f'{args.bag}: no JPEG of the stamp of detections {args.index}', file=sys.stderr)
        return 1
    rows = from_cloud(cloud)
    found = [Detection(int(r['class_id']), float(r['score']), float(r['x_min']),
                       float(r['y_min']), float(r['x_max']), float(r['y_max'])) for r in rows]
    names = next(s.default for s in SPECS if s.name == 'class_names')
    cv2.imwrite(args.output, annotate(image_array(image), found, names))
    print(f'wrote {args.output}: {len(found)} box(es)')
    if args.camera_info:
        info = msgs['/camera/camera_info'][0][1]
        save_calibration(calibration_of(info, 'camera'), args.camera_info)
        print(f'wrote {args.camera_info}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
