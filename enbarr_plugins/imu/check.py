"""``enbarr check-device lsm9ds1`` and ``fxos8700``: the chips of one IMU board, without a vessel.

Opens the bus with the driver's own code (``ImuChips`` of the board), checks the WHO_AM_Is,
writes and reads back the configuration of the parameter defaults, waits for one sample and
prints it in SI units (FLU). ``--bus emulated`` puts the board's emulator on a private fake
bus for the check. Lives apart from the drivers: it is the one place that needs both the
driver and the emulator.
"""

from __future__ import annotations

from collections.abc import Callable
import time
from typing import Any

import numpy as np

from enbarr_core.framework.errors import DeviceError
from enbarr_plugins import emulation
from enbarr_plugins.check import CheckTarget
from enbarr_plugins.imu import fxos8700, lsm9ds1
from enbarr_plugins.imu.common import Bus, I2cImuSettings, ImuChips, ImuSample
from enbarr_plugins.imu.fxos8700_emulator import attach_fxos8700
from enbarr_plugins.imu.lsm9ds1_emulator import attach_lsm9ds1
from enbarr_plugins.transport.i2c import FakeI2cBus


def check_lsm9ds1(target: CheckTarget) -> list[str]:
    """``enbarr check-device lsm9ds1``: identities, configuration and one sample in SI units."""
    return check_imu(target, lsm9ds1.default_settings, lsm9ds1.Lsm9ds1Chips,
                     lambda fake, addresses: attach_lsm9ds1(fake, *addresses))


def check_fxos8700(target: CheckTarget) -> list[str]:
    """``enbarr check-device fxos8700``: identities, configuration and one SI sample."""
    return check_imu(target, fxos8700.default_settings, fxos8700.Fxos8700Chips,
                     lambda fake, addresses: attach_fxos8700(fake, *addresses))


def wait_sample(chips: ImuChips, timeout: float) -> ImuSample:
    """Poll ``chips`` until a sample with a magnetometer reading comes (check-device)."""
    deadline = time.monotonic() + timeout
    gyro_accel = None
    while time.monotonic() < deadline:
        sample = chips.read()
        if sample is not None:
            if sample.mag is not None:
                return sample
            gyro_accel = sample
        time.sleep(0.005)
    if gyro_accel is not None:
        raise DeviceError(f'no magnetometer sample within {timeout:g} s (accel/gyro work)')
    raise DeviceError(f'no new sample within {timeout:g} s (status 0x{chips.status:02x}: '
                      'data-ready never set)')


def sample_lines(sample: ImuSample) -> list[str]:
    """Return one sample in SI units, for check-device."""
    def fmt(v: np.ndarray, scale: float = 1.0) -> str:
        return ' '.join(f'{x * scale:+.3f}' for x in v)
    lines = [f'gyro [rad/s] (FLU): {fmt(sample.gyro)}',
             f'accel [m/s^2] (FLU): {fmt(sample.accel)}']
    if sample.mag is not None:
        lines.append(f'mag [uT] (FLU): {fmt(sample.mag, 1e6)}')
    return lines


def check_imu(target: CheckTarget, default_settings: Callable[..., I2cImuSettings],
              chips_class: type[ImuChips],
              attach: Callable[[FakeI2cBus, tuple[int, ...]], object]) -> list[str]:
    """``enbarr check-device`` of an I2C IMU: identities, configuration, one sample in SI.

    ``default_settings(**changes)`` builds the driver's settings, ``chips_class`` its chips,
    ``attach(fake_bus, addresses)`` puts the emulated chips on a fake bus (``--bus emulated``:
    a private emulated bus for the check, withdrawn afterwards).
    """
    value = target.bus or '1'
    changes: dict[str, Any] = {'bus': value}
    if target.address is not None:
        changes['address'] = target.address
    try:
        s = default_settings(**changes)
    except ValueError as err:
        raise DeviceError(str(err)) from err
    addresses = chips_class.addresses(s)
    with emulation.checked_i2c_bus(value, lambda fake: attach(fake, addresses)) as opened:
        if opened != value:
            s = default_settings(**{**changes, 'bus': opened})
        bus = Bus(s.bus, min(target.timeout, 1.0))
        try:
            chips = chips_class(bus, s)
            lines = chips.open()
            sample = wait_sample(chips, target.timeout)
        finally:
            bus.close()
    return lines + sample_lines(sample)
