"""The I2C register layer over the fake bus: bytes, retries, and errors that name the device."""

from __future__ import annotations

import errno

import pytest

from enbarr_core.framework.errors import DeviceError
from enbarr_plugins.transport.i2c import FakeI2cBus, I2cDevice, RegisterMap


@pytest.fixture
def bus() -> FakeI2cBus:
    return FakeI2cBus()


def device(bus: FakeI2cBus, **kwargs) -> I2cDevice:
    return I2cDevice(bus, 0x40, bus_name='i2c-1', retry_delay=0.0, **kwargs)


def test_byte_registers_read_back_what_was_written(bus):
    regs = bus.attach(0x40)
    dev = device(bus)
    dev.write_u8(0x00, 0x21)
    assert regs.registers[0x00] == 0x21
    assert dev.read_u8(0x00) == 0x21
    assert list(bus.log) == [('write', 0x40, 0x00, b'\x21'), ('read', 0x40, 0x00, b'\x21')]


def test_block_transfers_auto_increment(bus):
    regs = bus.attach(0x40, RegisterMap({0x3B: 0x12, 0x3C: 0x34}))
    dev = device(bus)
    assert dev.read_block(0x3B, 2) == b'\x12\x34'
    dev.write_block(0x06, b'\x00\x00\x33\x01')
    assert bytes(regs.registers[0x06:0x0A]) == b'\x00\x00\x33\x01'


def test_update_bits_keeps_the_other_bits(bus):
    regs = bus.attach(0x40, RegisterMap({0x00: 0b1000_0001}))
    device(bus).update_bits(0x00, 0b0001_0000, 0xFF)
    assert regs.registers[0x00] == 0b1001_0001


def test_a_nack_is_retried_within_the_bound(bus):
    bus.attach(0x40, RegisterMap({0x10: 7}))
    dev = device(bus, retries=2)
    bus.nack(0x40, 2)
    assert dev.read_u8(0x10) == 7
    assert dev.errors == 2 and dev.failures == 0


def test_persistent_nack_names_bus_address_and_register(bus):
    bus.attach(0x40)
    dev = device(bus, retries=2)
    bus.nack(0x40, 3)
    with pytest.raises(DeviceError, match=r'i2c-1 0x40: read register 0x10 failed after 3 '
                       r'attempts: EREMOTEIO') as info:
        dev.read_u8(0x10)
    assert isinstance(info.value.__cause__, OSError)
    assert info.value.__cause__.errno == errno.EREMOTEIO
    assert dev.failures == 1


def test_a_stall_is_a_timeout_error(bus):
    bus.attach(0x40)
    dev = device(bus, retries=0)
    bus.stall(0x40)
    with pytest.raises(DeviceError, match='write register 0x01 failed after 1 attempts: '
                       'ETIMEDOUT'):
        dev.write_u8(0x01, 3)
    dev.write_u8(0x01, 3)  # the stall is over


def test_an_absent_device_nacks(bus):
    with pytest.raises(DeviceError, match='i2c-1 0x40'):
        device(bus).read_u8(0)
    bus.attach(0x40)
    assert device(bus).read_u8(0) == 0
    bus.detach(0x40)
    with pytest.raises(DeviceError, match='EREMOTEIO'):
        device(bus).read_u8(0)


def test_short_block_read_is_a_device_error(bus):
    class Short:
        def read(self, register, length):
            return b'\x01'

        def write(self, register, data):
            pass

    bus.attach(0x40, Short())
    with pytest.raises(DeviceError, match='expected 6 bytes, got 1'):
        device(bus).read_block(0x3B, 6)


@pytest.mark.parametrize('call, match', [
    (lambda d: d.read_u8(0x100), 'register'),
    (lambda d: d.write_u8(0, 256), 'value'),
    (lambda d: d.read_block(0, 33), 'length'),
    (lambda d: d.write_block(0, b''), 'data'),
])
def test_bad_arguments_name_the_field(bus, call, match):
    bus.attach(0x40)
    with pytest.raises(ValueError, match=match):
        call(device(bus))


def test_address_must_be_seven_bit(bus):
    with pytest.raises(ValueError, match='address: 0x80'):
        I2cDevice(bus, 0x80)


def test_close_closes_the_bus(bus):
    dev = device(bus)
    dev.close()
    assert bus.closed
    with pytest.raises(DeviceError, match='EBADF'):
        dev.read_u8(0)


def test_the_transfer_log_is_bounded() -> None:
    """An emulated vessel reads its IMU 400 times a second for hours: the log must not grow."""
    from enbarr_plugins.transport.i2c import LOG_LENGTH
    bus = FakeI2cBus()
    bus.attach(0x40)
    for i in range(LOG_LENGTH + 5):
        bus.write_byte_data(0x40, 0x00, i & 0xFF)
    assert len(bus.log) == LOG_LENGTH
    assert bus.log[-1] == ('write', 0x40, 0x00, bytes([(LOG_LENGTH + 4) & 0xFF]))
