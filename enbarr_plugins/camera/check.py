"""``enbarr check-device camera [--device DEVICE]``: open the source, read one frame.

With ``--device emulated`` it writes the emulator's test video to a temporary directory and
checks against it (the command's own test). Apart from the driver so that the driver never
imports its emulator.
"""

from __future__ import annotations

import tempfile
import time

from enbarr_core.framework.errors import DeviceError
from enbarr_plugins.camera.capture import describe, open_capture, parse_device, Source
from enbarr_plugins.camera.pattern_video import write_test_video
from enbarr_plugins.check import CheckTarget


def check_device(target: CheckTarget) -> list[str]:
    """``enbarr check-device camera``: open the source, read one frame, print its size/rate."""
    value = target.device or '0'
    try:
        source = parse_device(value)
    except ValueError as err:
        raise DeviceError(str(err)) from err
    emulator = None
    if source.emulated:
        emulator = tempfile.TemporaryDirectory(prefix='enbarr-camera-check-')
        source = Source(None, write_test_video(emulator.name, 640, 480, 15.0, 15), False)
    try:
        cap = open_capture(source, value)
        try:
            deadline = time.monotonic() + target.timeout
            ok, frame = cap.read()
            while not ok and time.monotonic() < deadline:
                time.sleep(0.05)
                ok, frame = cap.read()
            if not ok:
                raise DeviceError(f'camera {value}: opened, but no frame within '
                                  f'{target.timeout:g} s')
            h, w = frame.shape[:2]
            return [f'camera {value}: {describe(cap)}', f'one frame: {w}x{h} bgr8']
        finally:
            cap.release()
    finally:
        if emulator is not None:
            emulator.cleanup()
