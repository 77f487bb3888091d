"""Node tests of both I2C IMU drivers and their emulators: constructing opens nothing.

``bringup --check`` builds every node of a profile: a driver that read WHO_AM_I or wrote its
ranges while being built would reconfigure a running vessel's IMU. The emulators plug their
chips into the shared bus when started, so a check leaves no bus behind either.
"""

from __future__ import annotations

import pytest

from enbarr_core.framework.errors import DeviceError
from enbarr_plugins import emulation
from enbarr_plugins.imu.fxos8700 import Fxos8700ImuNode
from enbarr_plugins.imu.fxos8700_emulator import Fxos8700EmulatorNode
from enbarr_plugins.imu.lsm9ds1 import Lsm9ds1ImuNode
from enbarr_plugins.imu.lsm9ds1_emulator import Lsm9ds1EmulatorNode
from support.devices import pass_time
from support.imu import Rig

#: driver, emulator, and the first transfer of an open: WHO_AM_I of the first chip (address,
#: register, value typed from the data sheets: LSM9DS1 DocID025715 0x6B, 0x0F = 0x68;
#: FXOS8700CQ 0x1F, 0x0D = 0xC7).
BOARDS = [
    pytest.param(Lsm9ds1ImuNode, Lsm9ds1EmulatorNode, (0x6B, 0x0F, 0x68), id='lsm9ds1'),
    pytest.param(Fxos8700ImuNode, Fxos8700EmulatorNode, (0x1F, 0x0D, 0xC7), id='fxos8700'),
]


@pytest.mark.parametrize('driver, emulator, first_read', BOARDS)
def test_a_constructed_driver_touches_nothing_until_started(context, executor, spin, driver,
                                                            emulator, first_read):
    rig = Rig(context, executor, driver, emulator, start=False)
    pass_time(executor, spin, rig.probe)
    assert list(rig.bus.log) == []                       # not one transfer on the bus
    assert rig.raw == [] and rig.mag == [] and rig.diag == []
    assert not rig.driver.connected and rig.driver.faults == 0
    rig.driver.start()
    address, register, value = first_read
    assert rig.bus.log[0] == ('read', address, register, bytes([value]))
    assert rig.publishing()


@pytest.mark.parametrize('emulator', [Lsm9ds1EmulatorNode, Fxos8700EmulatorNode])
def test_an_emulator_plugs_its_chips_in_when_started(context, executor, emulator):
    node = emulator(context=context)
    executor.add_node(node)
    with pytest.raises(DeviceError, match='no i2c emulator'):
        emulation.lookup('i2c', 'emulated')
    node.start()
    bus = emulation.lookup('i2c', 'emulated')
    assert sorted(bus.devices) == sorted(node.chips)
    executor.remove_node(node)
    node.destroy_node()
    with pytest.raises(DeviceError, match='no i2c emulator'):
        emulation.lookup('i2c', 'emulated')
