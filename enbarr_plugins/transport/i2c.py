"""Register access to one I2C device on a Linux ``i2c-dev`` bus (through smbus2), and a fake bus.

``I2cDevice`` reads and writes the 8-bit registers of one device (a PCA9685 PWM driver, an
IMU) with a bounded number of retries; every failure is a ``DeviceError`` that names the bus,
the address and the register. ``open_i2c`` opens ``/dev/i2c-N`` and sets the adapter's own
timeout and retry count where the adapter allows (``I2C_TIMEOUT`` and ``I2C_RETRIES`` ioctls
of ``linux/i2c-dev.h``; the timeout is in units of 10 ms): an I2C transfer is done by the
kernel, so that is the only bound on how long one transfer can block.

``FakeI2cBus`` implements the subset of smbus2's ``SMBus`` interface that ``I2cDevice`` uses
(``write_byte``, ``read_byte_data``, ``write_byte_data``, ``read_i2c_block_data``,
``write_i2c_block_data``, ``close``), backed by a 256-byte register map or an emulator object
per address, and injects the failures a real bus shows: a NACK (``EREMOTEIO``, what Linux
adapters return when no device acknowledges) and a stall (``ETIMEDOUT``, a device holding SCL low).
References: smbus2 0.6 (https://github.com/kplindegaard/smbus2), the Linux kernel's
Documentation/i2c/dev-interface.rst and include/uapi/linux/i2c-dev.h.
"""

from __future__ import annotations

from collections import deque
import errno
import fcntl
import time
from typing import Any, Protocol

from enbarr_core.framework.errors import DeviceError

#: ioctl requests of linux/i2c-dev.h.
I2C_RETRIES = 0x0701
I2C_TIMEOUT = 0x0702
#: Transfers kept in ``FakeI2cBus.log``.
LOG_LENGTH = 10000
#: Longest block of one SMBus/I2C block transfer in smbus2 [bytes].
MAX_BLOCK = 32


class SMBusLike(Protocol):
    """The part of ``smbus2.SMBus`` that ``I2cDevice`` uses."""

    def write_byte(self, i2c_addr: int, value: int) -> None: ...  # noqa: D102

    def read_byte_data(self, i2c_addr: int, register: int) -> int: ...  # noqa: D102

    def write_byte_data(self, i2c_addr: int, register: int, value: int) -> None: ...  # noqa: D102

    def read_i2c_block_data(self, i2c_addr: int, register: int,  # noqa: D102
                            length: int) -> list[int]: ...

    def write_i2c_block_data(self, i2c_addr: int, register: int,  # noqa: D102
                             data: list[int]) -> None: ...

    def close(self) -> None: ...  # noqa: D102


def open_i2c(bus_number: int, *, timeout: float = 0.05, adapter_retries: int = 1) -> Any:
    """Open ``/dev/i2c-<bus_number>`` as an ``smbus2.SMBus``.

    The adapter's timeout [s] (rounded up to 10 ms) and retry count are set where the adapter
    supports them; an adapter that refuses keeps its own (usually one second).
    """
    import smbus2
    try:
        bus = smbus2.SMBus(bus_number)
    except OSError as err:
        raise DeviceError(f'i2c-{bus_number}: cannot open /dev/i2c-{bus_number}: '
                          f'{err.strerror or err}') from err
    for request, value in ((I2C_TIMEOUT, max(1, int(-(-timeout // 0.01)))),
                           (I2C_RETRIES, adapter_retries)):
        try:
            fcntl.ioctl(bus.fd, request, value)
        except OSError:
            pass  # not every adapter driver implements these; its defaults then hold
    return bus


class I2cDevice:
    """The registers of one device at ``address`` on ``bus``.

    A transfer that fails with ``OSError`` is tried again up to ``retries`` more times,
    ``retry_delay`` [s] apart; then a ``DeviceError`` names the bus, the address, the register
    and the last error. ``bus_name`` is what the messages call the bus (``i2c-1``).
    """

    def __init__(self, bus: SMBusLike, address: int, *, bus_name: str = 'i2c',
                 retries: int = 2, retry_delay: float = 0.001) -> None:
        if not 0x03 <= address <= 0x77:
            raise ValueError(f'address: 0x{address:02x} is not a 7-bit device address '
                             '(0x03..0x77)')
        if retries < 0 or retry_delay < 0.0:
            raise ValueError(f'retries/retry_delay: must be >= 0, got {retries}, '
                             f'{retry_delay}')
        self.bus = bus
        self.address = address
        self.bus_name = bus_name
        self.retries = retries
        self.retry_delay = retry_delay
        self.errors = 0   # failed transfers, each retry counted
        self.failures = 0  # DeviceErrors raised (retries exhausted)

    @property
    def name(self) -> str:
        """Bus and address, as messages and diagnostics show them (``i2c-1 0x40``)."""
        return f'{self.bus_name} 0x{self.address:02x}'

    def _transfer(self, register: int, what: str, call: Any, *args: Any) -> Any:
        if not 0 <= register <= 0xFF:
            raise ValueError(f'register: 0x{register:x} is not an 8-bit register')
        for attempt in range(self.retries + 1):
            try:
                return call(self.address, register, *args)
            except OSError as err:
                self.errors += 1
                if attempt == self.retries:
                    self.failures += 1
                    reason = (errno.errorcode.get(err.errno, str(err.errno))
                              if err.errno else str(err))
                    raise DeviceError(
                        f'{self.name}: {what} 0x{register:02x} failed after '
                        f'{self.retries + 1} attempts: {reason} ({err.strerror or err})'
                    ) from err
                if self.retry_delay:
                    time.sleep(self.retry_delay)
        raise AssertionError('unreachable')

    def command(self, command: int) -> None:
        """Send the one-byte ``command`` alone (SMBus send byte).

        A command-driven chip's reset or conversion start: no register behind it.
        """
        self._transfer(command, 'command', self.bus.write_byte)

    def read_u8(self, register: int) -> int:
        """One register's byte."""
        return self._transfer(register, 'read register', self.bus.read_byte_data)

    def write_u8(self, register: int, value: int) -> None:
        """Write one register."""
        if not 0 <= value <= 0xFF:
            raise ValueError(f'value: {value} is not a byte')
        self._transfer(register, 'write register', self.bus.write_byte_data, value)

    def read_block(self, register: int, length: int) -> bytes:
        """``length`` (1..32) consecutive registers from ``register`` (auto-increment)."""
        if not 1 <= length <= MAX_BLOCK:
            raise ValueError(f'length: must be 1..{MAX_BLOCK}, got {length}')
        data = self._transfer(register, 'read register', self.bus.read_i2c_block_data, length)
        if len(data) != length:
            self.failures += 1
            raise DeviceError(f'{self.name}: read register 0x{register:02x}: expected '
                              f'{length} bytes, got {len(data)}')
        return bytes(data)

    def write_block(self, register: int, data: bytes) -> None:
        """Write ``data`` (1..32 bytes) to consecutive registers from ``register``."""
        if not 1 <= len(data) <= MAX_BLOCK:
            raise ValueError(f'data: must be 1..{MAX_BLOCK} bytes, got {len(data)}')
        self._transfer(register, 'write register', self.bus.write_i2c_block_data, list(data))

    def update_bits(self, register: int, mask: int, value: int) -> None:
        """Read-modify-write: set the bits of ``mask`` in ``register`` to those of ``value``."""
        old = self.read_u8(register)
        self.write_u8(register, (old & ~mask & 0xFF) | (value & mask))

    def close(self) -> None:
        """Close the bus (when this device owns it); never raises."""
        try:
            self.bus.close()
        except OSError:
            pass


class RegisterEmulator(Protocol):
    """A device behind ``FakeI2cBus``: how it answers reads and takes writes.

    A send byte (``write_byte``) arrives as a write of no data to the byte's "register".
    """

    def read(self, register: int, length: int) -> bytes: ...  # noqa: D102

    def write(self, register: int, data: bytes) -> None: ...  # noqa: D102


class RegisterMap:
    """A plain device: 256 byte registers, auto-increment, writes stored as they come."""

    def __init__(self, registers: dict[int, int] | None = None) -> None:
        self.registers = bytearray(256)
        for register, value in (registers or {}).items():
            self.registers[register] = value

    def read(self, register: int, length: int) -> bytes:
        """``length`` registers from ``register`` (wrapping at 0xff)."""
        return bytes(self.registers[(register + i) & 0xFF] for i in range(length))

    def write(self, register: int, data: bytes) -> None:
        """Store ``data`` from ``register`` on."""
        for i, value in enumerate(data):
            self.registers[(register + i) & 0xFF] = value


class FakeI2cBus:
    """An in-memory I2C bus with the ``SMBus`` calls ``I2cDevice`` makes; see the module doc.

    ``attach(address, device)`` puts a ``RegisterMap`` (or any ``RegisterEmulator``) at an
    address; an empty address NACKs. ``nack(address, n)`` / ``stall(address, n)`` make the
    next ``n`` transfers to it fail. ``log`` records every transfer (for byte-level tests).
    """

    def __init__(self) -> None:
        self.devices: dict[int, RegisterEmulator] = {}
        #: The last ``LOG_LENGTH`` transfers (an emulated vessel's IMU reads 400 times a second).
        self.log: deque[tuple[str, int, int, bytes]] = deque(maxlen=LOG_LENGTH)
        self.closed = False
        self._faults: dict[int, list[int]] = {}

    def attach(self, address: int, device: RegisterEmulator | None = None) -> RegisterEmulator:
        """Put ``device`` (a fresh ``RegisterMap`` when None) at ``address``; return it."""
        device = RegisterMap() if device is None else device
        self.devices[address] = device
        return device

    def detach(self, address: int) -> None:
        """Unplug the device at ``address``: it NACKs from now on."""
        self.devices.pop(address, None)

    def nack(self, address: int, count: int = 1) -> None:
        """Make the next ``count`` transfers to ``address`` go unacknowledged."""
        self._faults.setdefault(address, []).extend([errno.EREMOTEIO] * count)

    def stall(self, address: int, count: int = 1) -> None:
        """Make the next ``count`` transfers to ``address`` time out (SCL held low)."""
        self._faults.setdefault(address, []).extend([errno.ETIMEDOUT] * count)

    def _device(self, address: int) -> RegisterEmulator:
        if self.closed:
            raise OSError(errno.EBADF, 'bus is closed')
        faults = self._faults.get(address)
        if faults:
            code = faults.pop(0)
            raise OSError(code, 'Remote I/O error' if code == errno.EREMOTEIO
                          else 'Connection timed out')
        device = self.devices.get(address)
        if device is None:
            raise OSError(errno.EREMOTEIO, 'Remote I/O error')
        return device

    def write_byte(self, i2c_addr: int, value: int) -> None:
        """SMBus send byte: ``value`` alone, handed to the device as a write of no data."""
        self._device(i2c_addr).write(value, b'')
        self.log.append(('write', i2c_addr, value, b''))

    def read_byte_data(self, i2c_addr: int, register: int) -> int:
        """SMBus read byte data."""
        value = self._device(i2c_addr).read(register, 1)[0]
        self.log.append(('read', i2c_addr, register, bytes([value])))
        return value

    def write_byte_data(self, i2c_addr: int, register: int, value: int) -> None:
        """SMBus write byte data."""
        self._device(i2c_addr).write(register, bytes([value]))
        self.log.append(('write', i2c_addr, register, bytes([value])))

    def read_i2c_block_data(self, i2c_addr: int, register: int, length: int) -> list[int]:
        """I2C block read (auto-increment from ``register``)."""
        data = self._device(i2c_addr).read(register, length)
        self.log.append(('read', i2c_addr, register, bytes(data)))
        return list(data)

    def write_i2c_block_data(self, i2c_addr: int, register: int, data: list[int]) -> None:
        """I2C block write (auto-increment from ``register``)."""
        self._device(i2c_addr).write(register, bytes(data))
        self.log.append(('write', i2c_addr, register, bytes(data)))

    def close(self) -> None:
        """Close the bus."""
        self.closed = True
