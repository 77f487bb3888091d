"""``enbarr check-device rplidar --port PORT``: identity, health and one revolution.

With ``--port emulated`` it starts the emulator in this process and checks against it (the
command's own test). Apart from the driver so that the driver never imports its emulator.
"""

from __future__ import annotations

import os
import time

import numpy as np

from enbarr_core.framework.errors import DeviceError
from enbarr_plugins.check import CheckTarget, device_endpoint
from enbarr_plugins.lidar.rplidar import (
    handshake, set_motor, stable_name_advice, start_scan, stop)
from enbarr_plugins.lidar.rplidar_emulator import RplidarEmulator
from enbarr_plugins.lidar.rplidar_protocol import BAUDRATE, ScanDecoder
from enbarr_plugins.lidar.scan import RevolutionAssembler
from enbarr_plugins.transport.serial_link import open_serial


def check_device(target: CheckTarget) -> list[str]:
    """``enbarr check-device rplidar --port PORT``: identity, health, one revolution."""
    port = target.port or '/dev/ttyUSB0'
    with device_endpoint(port, port, RplidarEmulator) as path:
        try:
            ser = open_serial(path, BAUDRATE, timeout=0.05)
        except DeviceError as err:
            if os.path.exists(path):
                raise
            raise DeviceError(f'{err}{stable_name_advice(path)}') from err
        try:
            info, health, resets = handshake(ser, port, target.timeout)
            start_scan(ser, port, target.timeout)
            decoder, assembler = ScanDecoder(), RevolutionAssembler()
            deadline = time.monotonic() + target.timeout
            revs: list[RevolutionAssembler.Revolution] = []
            while not revs:
                if time.monotonic() > deadline:
                    raise DeviceError(f'{port}: no full revolution within {target.timeout} s '
                                      f'({decoder.samples} samples, {decoder.sync_losses} '
                                      'sync losses)')
                start, _, angle, dist = decoder.feed(ser.read(max(1, ser.in_waiting)))
                revs = assembler.add(start, angle, dist, time.monotonic_ns())
            stop(ser, port)
            set_motor(ser, port, False)
        finally:
            ser.close()
    rev = revs[0]
    hits = rev.distance_mm > 0
    lines = [f'{port}: {info.describe()}', f'{port}: {health.describe()}'
             + (' (after RESET)' if resets else '')]
    line = (f'{port}: one revolution: {len(rev.angle_deg)} samples in {rev.duration:.3f} s, '
            f'{int(hits.sum())} returns')
    if hits.any():
        k = int(np.argmin(np.where(hits, rev.distance_mm, np.inf)))
        line += (f', nearest {rev.distance_mm[k] / 1000.0:.2f} m at '
                 f'{rev.angle_deg[k]:.1f} deg')
    return lines + [line]
