"""``enbarr bench``: a control chain, a whole profile or the recorder, measured (one JSON line).

The benchmarks are in ``enbarr_core.bench``; this is their command line.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
import json

from enbarr_core.commands import Command
from enbarr_core.commands.arguments import check_rate, check_seconds
from enbarr_core.framework.errors import EnbarrError

CHAIN_RATE = 400.0
CHAIN_SECONDS = 10.0
IDLE_SECONDS = 10.0
#: The chain rate a run takes [Hz] (the simulator and sensors refuse far less).
MAX_RATE = 10_000.0
PERCEPTION_SCANS = 500
PAIRS = 4
MAX_PAIRS = 50
VISION_FRAMES = 200

EPILOG = """\
--chain (default rov): drive the sensor -> filter -> control -> allocation -> actuator
chain in one process at --rate for --seconds after a 2 s warm-up; one JSON line of
figures (rate, latency, CPU per cycle, ROS overhead against the plain algorithms).

--profile NAME: run the whole profile under `enbarr bringup` (child processes, LOCALHOST,
ROS_DOMAIN_ID as set or random), warm up --warmup s, measure --seconds s from /proc, stop
it with SIGINT; one JSON line: the tree's share of a core (x6 for a Pi 4), the busiest
threads, per process, RSS at start and end. --record runs it twice back to back, without
and with a bag: cpu_us_per_recorded_message = the CPU difference / messages recorded in
the window; writer_cpu_us_per_recorded_message = the writer thread alone. --idle: the
profile's fixed cost instead (its nodes composed and spun, no source started).

--profile NAME --against BASE: what NAME costs beyond BASE (e.g. a feature switched off in
BASE): --pairs pairs (default 4) of runs, the two of a pair at the same time in two ROS
domains (the machine's other load then weighs on both); each pair's difference (whole and
per kind of thread, DDS ports dropped from names; they add up to the whole) and their mean,
median, spread and Pi 4 estimate. Needs two cores.

--recording: what the recorder costs per message, by message type and for the mix of
each chain (--messages per type, --repeat runs; the median is kept).

--perception: the CPU one 360-ray lidar scan costs, scan -> tracked obstacles (--scans
scans of a synthetic basin with walls and buoys; per-scan CPU, share of a core at 5.5 Hz
and its Raspberry Pi 4 estimate).

--camera: the CPU one simulated camera frame costs, rendered (sim_camera) and encoded as
JPEG (what the real camera pays for camera/image_raw/compressed), on --frames frames of the
ca_buoy scene (--scene NAME for another profile's world and frames) at --quality; the share of
a core at 15 fps and its Raspberry Pi 4 estimate; --png PATH writes the first frame.

--avoidance: what the collision avoidance's safety filter costs per step with --obstacles
obstacles (default 10): no barrier binding, pressed against them (the QP), the bare QP
solve; --repeat runs, the median kept; the share of a core at 50 Hz and the Pi 4 estimate.

--vision: the CPU one 640 x 480 camera frame costs the detector: the classical back end
(colour and shape) on --frames synthetic frames and, with --model PATH, an ONNX model in the
YOLOv8 layout (640 x 640 input, 80 classes; docs/vision.md); per-frame CPU, the share of a
core at 15 Hz and its Raspberry Pi 4 estimate.

--fusion: the CPU one detections message costs the fusion node (projecting --obstacles
obstacles, default 10, assigning the boxes, voting) over --frames messages, and republishing
an obstacles message with the classes; the share of a core at 15 detections/s and 5.5 scans/s
and its Raspberry Pi 4 estimate.

docs/benchmarks.md has our figures and how they were taken."""


class BenchCommand(Command):
    """``enbarr bench``."""

    help = 'measure a control chain, a whole profile or the recorder (prints JSON)'
    description = ('Measure one of: a control chain in one process (--chain, the default), '
                   'a whole profile as processes (--profile), the recorder (--recording), '
                   'the lidar perception (--perception), the camera (--camera), the camera '
                   'detector (--vision), the camera-lidar fusion (--fusion). '
                   'Figures depend on the machine and its load: run it alone.')
    epilog = EPILOG

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Declare what to measure and for how long."""
        from enbarr_core.bench import recording
        from enbarr_core.bench.profile_run import DEFAULT_SECONDS, DEFAULT_WARMUP
        what = parser.add_mutually_exclusive_group()
        what.add_argument('--chain', choices=('rov', 'saucer'),
                          help='rov: IMU -> thrusters (default); saucer: pose -> PWM')
        what.add_argument('--profile', metavar='NAME|PATH',
                          help='a whole profile under bringup instead (see below)')
        what.add_argument('--recording', action='store_true',
                          help='the recorder alone: CPU per recorded message')
        what.add_argument('--perception', action='store_true',
                          help='the lidar perception alone: CPU per scan')
        what.add_argument('--camera', action='store_true',
                          help='the simulated camera alone: CPU per frame, render and JPEG')
        what.add_argument('--vision', action='store_true',
                          help='the camera detector alone: CPU per frame')
        what.add_argument('--fusion', action='store_true',
                          help='the camera-lidar fusion alone: CPU per detections message')
        what.add_argument('--avoidance', action='store_true',
                          help='the collision avoidance safety filter alone: time per step')
        parser.add_argument('--obstacles', type=int, default=None, metavar='N',
                            help='--avoidance, --fusion: obstacles around the vessel '
                            '(default 10)')
        parser.add_argument('--rate', type=float, default=None,
                            help=f'--chain: chain rate in Hz (default {CHAIN_RATE:g})')
        parser.add_argument('--seconds', type=float, default=None,
                            help='measured duration: after a 2 s warm-up for --chain '
                            f'(default {CHAIN_SECONDS:g}), after --warmup for --profile '
                            f'(default {DEFAULT_SECONDS:g})')
        parser.add_argument('--warmup', type=float, default=None, metavar='W',
                            help="--profile: seconds before the window: start-up and "
                            f"bringup's 3 s discovery wait (default {DEFAULT_WARMUP:g})")
        parser.add_argument('--record', action='store_true',
                            help='--profile: run it without, then with a bag, back to back; '
                            'report messages recorded per second and CPU per recorded message')
        parser.add_argument('--set', action='append', default=[], metavar='NODE.PARAM=VALUE',
                            help='--profile: override a node parameter, as bringup --set '
                            '(repeatable)')
        parser.add_argument('--against', default=None, metavar='NAME|PATH',
                            help='--profile: measure it against this baseline profile, both '
                            'at once, in --pairs pairs; prints each pair and the mean '
                            'difference')
        parser.add_argument('--pairs', type=int, default=None, metavar='N',
                            help=f'--against: pairs of runs (default {PAIRS})')
        parser.add_argument('--idle', action='store_true',
                            help="--profile: the fixed cost instead: the profile's nodes "
                            'composed in this process and spun, none of their sources '
                            'started (nothing flows; watchdogs, reports, core timers and '
                            'parameter services run), CPU over --seconds after a 3 s warm-up')
        parser.add_argument('--messages', type=int, default=None, metavar='N',
                            help='--recording: messages per type in the long run '
                            f'(default {recording.DEFAULT_MESSAGES})')
        parser.add_argument('--repeat', type=int, default=None, metavar='N',
                            help='--recording: runs per case, the median kept '
                            f'(default {recording.DEFAULT_REPEAT})')
        parser.add_argument('--scans', type=int, default=None, metavar='N',
                            help=f'--perception: scans measured (default {PERCEPTION_SCANS})')
        parser.add_argument('--frames', type=int, default=None, metavar='N',
                            help='--camera, --vision: frames measured (default 150 for '
                            f'--camera, {VISION_FRAMES} for --vision)')
        parser.add_argument('--model', default=None, metavar='PATH',
                            help='--vision: an ONNX model (YOLOv8 layout, 640 x 640, 80 '
                            'classes) measured besides the classical back end')
        parser.add_argument('--quality', type=int, default=None, metavar='Q',
                            help='--camera: JPEG quality 1..100 (default 80)')
        parser.add_argument('--scene', default=None, metavar='PROFILE',
                            help='--camera: the profile whose world and frames are drawn '
                            '(default ca_buoy)')
        parser.add_argument('--png', default=None, metavar='PATH',
                            help='--camera: write the first frame as a PNG')

    def main(self, *, args: argparse.Namespace, argv: Sequence[str]) -> int:
        """Measure what was asked and print one JSON line."""
        camera_only = {'--quality': args.quality is not None,
                       '--scene': args.scene is not None, '--png': args.png is not None}
        if not args.camera and any(camera_only.values()):
            raise EnbarrError(f'{next(k for k, v in camera_only.items() if v)} is for --camera')
        if args.frames is not None and not (args.camera or args.vision or args.fusion):
            raise EnbarrError('--frames is for --camera, --vision and --fusion')
        if args.model is not None and not args.vision:
            raise EnbarrError('--model is for --vision')
        if (args.against is not None or args.pairs is not None) and (
                args.profile is None or args.idle):
            raise EnbarrError('--against and --pairs are for --profile (without --idle)')
        if args.camera:
            result = _camera(args)
        elif args.avoidance:
            result = _avoidance(args)
        elif args.recording:
            result = _recording(args)
        elif args.perception:
            result = _perception(args)
        elif args.vision:
            result = _vision(args)
        elif args.fusion:
            result = _fusion(args)
        elif args.profile is not None:
            result = _idle(args) if args.idle else _profile(args)
        else:
            result = _chain(args)
        print(json.dumps(result))
        return 0


def _refuse(args: argparse.Namespace, options: Sequence[str], why: str) -> None:
    """Refuse any of ``options`` that was given, saying ``why``."""
    given = {'--rate': args.rate is not None, '--seconds': args.seconds is not None,
             '--warmup': args.warmup is not None, '--record': args.record,
             '--set': bool(args.set), '--idle': args.idle,
             '--messages': args.messages is not None, '--repeat': args.repeat is not None,
             '--scans': args.scans is not None,
             '--obstacles': args.obstacles is not None}
    for option in options:
        if given[option]:
            raise EnbarrError(f'{option} {why}')


def _camera(args: argparse.Namespace) -> dict:
    from enbarr_core.bench import camera
    _refuse(args, ('--rate', '--seconds', '--warmup', '--record', '--set', '--idle',
                   '--messages', '--repeat', '--scans', '--obstacles'),
            'is not for --camera (it takes --frames, --quality, --scene, --png)')
    frames = camera.DEFAULT_FRAMES if args.frames is None else args.frames
    quality = camera.DEFAULT_QUALITY if args.quality is None else args.quality
    if frames < 10 or not 1 <= quality <= 100:
        raise EnbarrError(f'--frames must be >= 10 and --quality 1..100, got {frames} and '
                          f'{quality}')
    return camera.measure(frames, quality, args.scene or camera.DEFAULT_PROFILE, args.png)


def _avoidance(args: argparse.Namespace) -> dict:
    from enbarr_core.bench import avoidance
    _refuse(args, ('--rate', '--seconds', '--warmup', '--record', '--set', '--idle',
                   '--messages', '--scans'), 'is not for --avoidance')
    obstacles = avoidance.DEFAULT_OBSTACLES if args.obstacles is None else args.obstacles
    repeat = avoidance.DEFAULT_REPEAT if args.repeat is None else args.repeat
    if not (0 <= obstacles <= 1000) or repeat < 1:
        raise EnbarrError('--obstacles must be 0..1000 and --repeat at least 1')
    return avoidance.measure(obstacles, repeat)


def _chain(args: argparse.Namespace) -> dict:
    from enbarr_core.bench import chain
    _refuse(args, ('--record', '--set', '--warmup', '--idle'),
            'is for --profile; --chain runs the chain alone')
    _refuse(args, ('--messages', '--repeat'), 'is for --recording')
    _refuse(args, ('--scans',), 'is for --perception')
    _refuse(args, ('--obstacles',), 'is for --avoidance')
    rate = CHAIN_RATE if args.rate is None else args.rate
    seconds = CHAIN_SECONDS if args.seconds is None else args.seconds
    check_rate('--rate', rate, MAX_RATE)
    check_seconds('--seconds', seconds)
    return chain.measure(args.chain or 'rov', rate, seconds)


def _idle(args: argparse.Namespace) -> dict:
    from enbarr_core.bench import chain
    _refuse(args, ('--record', '--rate', '--warmup'), 'does not go with --idle: nothing '
            'flows there')
    _refuse(args, ('--messages', '--repeat'), 'is for --recording')
    _refuse(args, ('--scans',), 'is for --perception')
    _refuse(args, ('--obstacles',), 'is for --avoidance')
    seconds = IDLE_SECONDS if args.seconds is None else args.seconds
    check_seconds('--seconds', seconds)
    return chain.run_idle(args.profile, args.set, seconds)


def _profile(args: argparse.Namespace) -> dict:
    from enbarr_core.bench import profile_run
    if args.rate is not None:
        raise EnbarrError('--rate is for --chain: a profile runs at its own rates '
                          '(change them with --set NODE.rate=HZ)')
    _refuse(args, ('--messages', '--repeat'), 'is for --recording')
    _refuse(args, ('--scans',), 'is for --perception')
    _refuse(args, ('--obstacles',), 'is for --avoidance')
    seconds = profile_run.DEFAULT_SECONDS if args.seconds is None else args.seconds
    warmup = profile_run.DEFAULT_WARMUP if args.warmup is None else args.warmup
    check_seconds('--seconds', seconds)
    check_seconds('--warmup', warmup)
    if args.pairs is not None and args.against is None:
        raise EnbarrError('--pairs is for --against')
    if args.against is not None:
        if args.record:
            raise EnbarrError('--record does not go with --against')
        pairs = PAIRS if args.pairs is None else args.pairs
        if not 1 <= pairs <= MAX_PAIRS:
            raise EnbarrError(f'--pairs must be 1..{MAX_PAIRS}, got {pairs}')
        return profile_run.compare(args.profile, args.against, args.set, warmup, seconds,
                                   pairs)
    return profile_run.measure(args.profile, args.set, warmup, seconds, args.record)


def _recording(args: argparse.Namespace) -> dict:
    from enbarr_core.bench import recording
    _refuse(args, ('--rate', '--seconds', '--warmup', '--record', '--set', '--idle',
                   '--scans', '--obstacles'),
            'is not for --recording (it takes --messages and --repeat)')
    return recording.measure(
        recording.DEFAULT_MESSAGES if args.messages is None else args.messages,
        recording.DEFAULT_REPEAT if args.repeat is None else args.repeat)


def _perception(args: argparse.Namespace) -> dict:
    from enbarr_core.bench import perception
    _refuse(args, ('--rate', '--seconds', '--warmup', '--record', '--set', '--idle',
                   '--messages', '--repeat', '--obstacles'),
            'is not for --perception (it takes --scans)')
    scans = PERCEPTION_SCANS if args.scans is None else args.scans
    if scans < 50:
        raise EnbarrError(f'--scans must be >= 50 (the first 20 confirm the tracks), '
                          f'got {scans}')
    return perception.measure(scans)


def _fusion(args: argparse.Namespace) -> dict:
    from enbarr_core.bench import fusion
    _refuse(args, ('--rate', '--seconds', '--warmup', '--record', '--set', '--idle',
                   '--messages', '--repeat', '--scans'),
            'is not for --fusion (it takes --obstacles and --frames)')
    obstacles = fusion.DEFAULT_OBSTACLES if args.obstacles is None else args.obstacles
    frames = fusion.DEFAULT_MESSAGES if args.frames is None else args.frames
    if not 0 <= obstacles <= 1000 or frames < 20:
        raise EnbarrError(f'--obstacles must be 0..1000 and --frames >= 20, got {obstacles} '
                          f'and {frames}')
    return fusion.measure(obstacles, frames)


def _vision(args: argparse.Namespace) -> dict:
    from enbarr_core.bench import vision
    _refuse(args, ('--rate', '--seconds', '--warmup', '--record', '--set', '--idle',
                   '--messages', '--repeat', '--obstacles', '--scans'),
            'is not for --vision (it takes --frames and --model)')
    frames = VISION_FRAMES if args.frames is None else args.frames
    if frames < 10:
        raise EnbarrError(f'--frames must be >= 10, got {frames}')
    try:
        return vision.measure(frames, args.model)
    except ValueError as err:       # a model that cannot be read, or of another shape
        # the message names the detector's parameter first ('model_path: ...'): here --model
        raise EnbarrError(f'--model: {str(err).partition(": ")[2]}') from err
