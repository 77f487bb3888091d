"""TI INA219 current/power monitor: registers and conversions, no I/O.

Why the INA219 and not the ADS1115 of Navigator-class boards: the INA219 measures the bus
voltage and, across its shunt, the current on one chip with its own calibration register, as
the hobby ROV power modules built on it do; the ADS1115 is a bare ADC that needs an external
current-sense amplifier and divider whose scale lives outside the chip.

Registers (16 bits, big-endian on the wire; TI INA219 data sheet SBOS448, section 8.6):
configuration 0x00, shunt voltage 0x01 (signed, LSB 10 uV), bus voltage 0x02 (bits 15..3,
LSB 4 mV; bit 1 CNVR: a conversion is ready, bit 0 OVF: the power or current overflowed),
power 0x03 (LSB 20 x current LSB), current 0x04 (signed, LSB ``current_lsb``), calibration
0x05 = trunc(0.04096 / (current_lsb * shunt)). The chip's current and power registers read 0
until the calibration register is written (it resets to 0 on power-up and after a brown-out).
"""

from __future__ import annotations

from dataclasses import dataclass
import math

ADDRESS = 0x40
CONFIG, SHUNT_VOLTAGE, BUS_VOLTAGE, POWER, CURRENT, CALIBRATION = range(6)
#: Configuration: 32 V range (BRNG), gain /8 (320 mV shunt range), 12-bit bus ADC (BADC
#: 0011) and shunt ADC (SADC 0011), shunt and bus continuous: the chip's power-on value,
#: written anyway so that a chip someone reconfigured is put back.
CONFIG_32V_320MV_12BIT = 0x2000 | 0x1800 | 0x0180 | 0x0018 | 0x0007
CONFIG_RESET = 0x8000
SHUNT_LSB = 10e-6       # [V]
BUS_LSB = 4e-3          # [V]
CAL_NUMERATOR = 0.04096  # the data sheet's fixed scaling constant
POWER_LSB_FACTOR = 20
CNVR, OVF = 0x2, 0x1


def calibration(current_lsb: float, shunt: float) -> int:
    """Return the calibration register for ``current_lsb`` [A] and ``shunt`` [ohm] (ValueError)."""
    value = math.trunc(CAL_NUMERATOR / (current_lsb * shunt))
    if not 1 <= value <= 0xFFFE:
        raise ValueError(f'current_lsb/shunt: calibration {value} does not fit the register '
                         '(1..65534); choose a larger current_lsb')
    return value & 0xFFFE   # bit 0 is read-only and always 0


def signed16(raw: int) -> int:
    """Return the two's complement value of a 16-bit register."""
    return raw - 0x10000 if raw & 0x8000 else raw


@dataclass(frozen=True)
class BusVoltage:
    """The bus voltage register decoded."""

    volts: float
    ready: bool       # CNVR
    overflow: bool    # OVF: current and power are out of range


def bus_voltage(raw: int) -> BusVoltage:
    """Decode the bus voltage register (bits 15..3, LSB 4 mV)."""
    return BusVoltage((raw >> 3) * BUS_LSB, bool(raw & CNVR), bool(raw & OVF))


def current(raw: int, current_lsb: float) -> float:
    """Return the current register in amperes."""
    return signed16(raw) * current_lsb


def shunt_voltage(raw: int) -> float:
    """Return the shunt voltage register in volts."""
    return signed16(raw) * SHUNT_LSB
