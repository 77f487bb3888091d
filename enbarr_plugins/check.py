"""``enbarr check-device KIND``: talk to one device, print what it is, without a vessel.

This module is the registry: ``CheckTarget`` (what the command line names) and ``CHECKS``
(KIND -> ``'module:function'``), imported on demand so that listing the kinds imports no
driver. Each kind's check lives in a check module of its own beside the driver
(``enbarr_plugins/<kind>/check.py``), apart from the driver and its emulator: it uses both
(``emulated`` runs the emulator in the process), and neither imports it.

A check is ``check_device(target: CheckTarget) -> list[str]``: it opens the device named by
``target`` with the driver's own code, reads its identity and one sample (or sends one neutral
command), closes it and returns the lines to print. A device that is absent, silent or not
what it should be raises ``DeviceError`` naming the port, bus, address or host and what was
found. ``emulated`` as the port, bus, host or device starts this package's emulator of that
device in the process and checks against it (the command's own test); ``device_endpoint``
does that for an emulator that serves an endpoint (a pty, a loopback address).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
import importlib
from typing import Protocol, TypeVar

from enbarr_plugins import emulation

E = TypeVar('E')
E_co = TypeVar('E_co', covariant=True)

#: KIND -> 'module:function', the ``check_device`` of each device this package drives.
#: One line per kind.
CHECKS: dict[str, str] = {
    'pca9685': 'enbarr_plugins.thrusters.check:check_pca9685',
    'lsm9ds1': 'enbarr_plugins.imu.check:check_lsm9ds1',
    'fxos8700': 'enbarr_plugins.imu.check:check_fxos8700',
    'ms5837': 'enbarr_plugins.pressure.check:check_ms5837',
    'ina219': 'enbarr_plugins.power.check:check_ina219',
    'bmp280': 'enbarr_plugins.hull.check:check_bmp280',
    'arduino': 'enbarr_plugins.arduino.check:check_device',
    'rplidar': 'enbarr_plugins.lidar.check:check_device',
    'camera': 'enbarr_plugins.camera.check:check_device',
    'qualisys': 'enbarr_plugins.mocap.check:check_device',
    'ds4': 'enbarr_plugins.joystick.check:check_device',
    'gpio': 'enbarr_plugins.io.check:check_gpio',
}


@dataclass(frozen=True)
class CheckTarget:
    """Which device to check; a device kind reads the fields it needs (None: its default)."""

    port: str | None = None        # serial port (/dev/ttyACM0) or 'emulated'
    bus: str | None = None         # I2C bus number (1) or 'emulated'
    address: int | None = None     # I2C address
    host: str | None = None        # network host or 'emulated' (port: the TCP port)
    device: str | None = None      # V4L2 index, video file, /dev/input/eventN or 'emulated'
    name: str | None = None        # a rigid body (motion capture), a pin (GPIO)
    timeout: float = 2.0           # longest wait for any answer [s]


def checker(kind: str) -> Callable[[CheckTarget], list[str]]:
    """Return the ``check_device`` function of ``kind``; ``KeyError`` naming the known kinds."""
    if kind not in CHECKS:
        raise KeyError(f'no device check {kind!r}; known: {", ".join(sorted(CHECKS))}')
    module_name, _, attr = CHECKS[kind].partition(':')
    return getattr(importlib.import_module(module_name), attr)


class EndpointEmulator(Protocol[E_co]):
    """An emulator that serves its device on an endpoint (a pty path, a loopback address)."""

    def start(self) -> E_co:
        """Serve the device; return the endpoint the driver opens."""

    def stop(self) -> None:
        """Stop serving; the endpoint closes."""


@contextmanager
def device_endpoint(value: str, endpoint: E,
                    emulator: Callable[[], EndpointEmulator[E]]) -> Iterator[E]:
    """Yield the endpoint a check opens: the device's own, or its emulator's.

    ``endpoint`` is the device's; when ``value`` (the port, the host ...) is ``emulated``, the
    emulator ``emulator()`` builds is started here and its endpoint yielded, and it is stopped
    on the way out.
    """
    if not emulation.is_emulated(value):
        yield endpoint
        return
    running = emulator()
    served = running.start()
    try:
        yield served
    finally:
        running.stop()
