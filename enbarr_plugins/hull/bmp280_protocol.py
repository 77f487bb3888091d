"""Bosch BMP280 (and the BME280's pressure and temperature) over I2C: registers, compensation.

Pure: no ROS, no I/O. Every number is from the BMP280 data sheet (Bosch Sensortec
BST-BMP280-DS001): the memory map (section 4.2), the control registers ``ctrl_meas`` and
``config`` (4.3.4, 4.3.5), the oversampling settings (3.3.1, 3.3.2), the measurement time
(3.8.2: t_measure,max = 1.25 + 2.3 * T_oversampling + (2.3 * P_oversampling + 0.575) ms),
the trimming parameters' layout (3.11.2) and the compensation in integers (3.11.3: 32-bit for
the temperature, 64-bit for the pressure), with the worked example of 3.12 pinned in
``test/plugins/hull/test_bmp280.py``. The BME280 (chip id 0x60) keeps the same registers,
trimming layout and formulas for these two quantities; its humidity is not read here.

Registers: calibration 0x88..0x9F (dig_T1..dig_P9, 16-bit little-endian; T1 and P1 unsigned),
chip id 0xD0, soft reset 0xE0 (write 0xB6), status 0xF3 (bit 3 measuring, bit 0 im_update),
ctrl_meas 0xF4 (osrs_t 7:5, osrs_p 4:2, mode 1:0), config 0xF5 (t_sb 7:5, filter 4:2),
data 0xF7..0xFC: press_msb, press_lsb, press_xlsb (7:4), temp_msb, temp_lsb, temp_xlsb
(7:4), 20-bit values read in one burst (the chip's shadowing keeps one burst consistent).
A skipped measurement reads 0x80000.

Integer arithmetic as the data sheet writes it: its right shifts are arithmetic (floor) on
signed values and its one division (in the pressure) truncates toward zero, as C's does.
"""

from __future__ import annotations

from dataclasses import dataclass

#: 7-bit I2C address with SDO to GND (0x76) or to VDDIO (0x77).
ADDRESSES = (0x76, 0x77)
CHIP_ID = 0xD0
CHIP_IDS = {0x58: 'BMP280', 0x60: 'BME280'}
RESET = 0xE0
RESET_WORD = 0xB6
STATUS = 0xF3
CTRL_MEAS = 0xF4
CONFIG = 0xF5
DATA = 0xF7               # press_msb .. temp_xlsb: 6 bytes
DATA_LENGTH = 6
CALIBRATION = 0x88        # dig_T1 .. dig_P9: 24 bytes
CALIBRATION_LENGTH = 24
SKIPPED = 0x80000         # a data register of a measurement that was skipped (or not yet run)
MODE_SLEEP, MODE_FORCED, MODE_NORMAL = 0b00, 0b01, 0b11
#: Time after power-on or a soft reset before the chip answers (start-up time) [s].
STARTUP_TIME = 0.002

#: Oversampling -> its 3-bit code in ctrl_meas (0: the measurement skipped).
OVERSAMPLING = {0: 0b000, 1: 0b001, 2: 0b010, 4: 0b011, 8: 0b100, 16: 0b101}
#: IIR filter coefficient -> its 3-bit code in config.
FILTER = {0: 0b000, 2: 0b001, 4: 0b010, 8: 0b011, 16: 0b100}
#: Standby time in normal mode [ms] -> its 3-bit code in config (t_sb).
STANDBY_MS = {0.5: 0b000, 62.5: 0b001, 125.0: 0b010, 250.0: 0b011, 500.0: 0b100,
              1000.0: 0b101, 2000.0: 0b110, 4000.0: 0b111}


class CalibrationError(ValueError):
    """The trimming parameters read back are not a programmed chip's."""


def _choice(name: str, value: float, table: dict[float, int] | dict[int, int]) -> int:
    if value not in table:
        raise ValueError(f"{name}: {value:g} is not one of the chip's "
                         f"({', '.join(f'{k:g}' for k in table)})")
    return table[value]  # type: ignore[index]


def ctrl_meas(osrs_t: int, osrs_p: int, mode: int) -> int:
    """Return the ctrl_meas byte: temperature and pressure oversampling, power mode."""
    if mode not in (MODE_SLEEP, MODE_FORCED, MODE_NORMAL):
        raise ValueError(f'mode: {mode} is not sleep (0), forced (1) or normal (3)')
    return (_choice('osrs_t', osrs_t, OVERSAMPLING) << 5
            | _choice('osrs_p', osrs_p, OVERSAMPLING) << 2 | mode)


def config(standby_ms: float, filter_coefficient: int) -> int:
    """Return the config byte: standby time in normal mode, IIR filter (SPI 3-wire off)."""
    return (_choice('standby', standby_ms, STANDBY_MS) << 5
            | _choice('filter', filter_coefficient, FILTER) << 2)


def measurement_time(osrs_t: int, osrs_p: int) -> float:
    """Return the longest time one measurement takes [s] (3.8.2, maximum)."""
    ms = 1.25 + 2.3 * osrs_t + ((2.3 * osrs_p + 0.575) if osrs_p else 0.0)
    return ms / 1000.0


@dataclass(frozen=True)
class Calibration:
    """The chip's trimming parameters dig_T1..dig_T3, dig_P1..dig_P9."""

    t: tuple[int, int, int]
    p: tuple[int, int, int, int, int, int, int, int, int]

    @classmethod
    def from_bytes(cls, data: bytes) -> Calibration:
        """Decode the 24 bytes from 0x88; ``CalibrationError`` when they cannot be a chip's.

        dig_T1 and dig_P1 are unsigned and never 0 on a programmed part (the pressure formula
        divides by a term scaled by dig_P1); all-0x00 or all-0xFF reads are a bus or a chip
        that is not there.
        """
        if len(data) != CALIBRATION_LENGTH:
            raise CalibrationError(f'calibration: expected {CALIBRATION_LENGTH} bytes, '
                                   f'got {len(data)}')
        words = [int.from_bytes(data[i:i + 2], 'little', signed=i not in (0, 6))
                 for i in range(0, CALIBRATION_LENGTH, 2)]
        if words[0] == 0 or words[3] == 0 or data in (bytes(24), b'\xff' * 24):
            raise CalibrationError('calibration: dig_T1 or dig_P1 reads 0 (or every byte '
                                   'is the same): not a programmed BMP280')
        return cls(t=(words[0], words[1], words[2]),
                   p=(words[3], words[4], words[5], words[6], words[7], words[8], words[9],
                      words[10], words[11]))


def raw_values(data: bytes) -> tuple[int, int]:
    """Return (adc_P, adc_T), 20 bits each, from the 6 data bytes from 0xF7."""
    if len(data) != DATA_LENGTH:
        raise ValueError(f'data: expected {DATA_LENGTH} bytes, got {len(data)}')
    adc_p = (data[0] << 12) | (data[1] << 4) | (data[2] >> 4)
    adc_t = (data[3] << 12) | (data[4] << 4) | (data[5] >> 4)
    return adc_p, adc_t


def t_fine(adc_t: int, cal: Calibration) -> int:
    """Return the data sheet's t_fine (the temperature carried into the pressure formula)."""
    t1, t2, t3 = cal.t
    var1 = (((adc_t >> 3) - (t1 << 1)) * t2) >> 11
    var2 = (((((adc_t >> 4) - t1) * ((adc_t >> 4) - t1)) >> 12) * t3) >> 14
    return var1 + var2


def temperature_centi(fine: int) -> int:
    """Return the temperature in 0.01 degC from ``t_fine`` (5123 is 51.23 degC)."""
    return (fine * 5 + 128) >> 8


def pressure_q24_8(adc_p: int, fine: int, cal: Calibration) -> int:
    """Return the pressure in Pa as Q24.8 (24674867 is 96386.2 Pa).

    0 if dig_P1 made the divisor 0 (the data sheet's guard against a division by zero).
    """
    p1, p2, p3, p4, p5, p6, p7, p8, p9 = cal.p
    var1 = fine - 128000
    var2 = var1 * var1 * p6
    var2 = var2 + ((var1 * p5) << 17)
    var2 = var2 + (p4 << 35)
    var1 = ((var1 * var1 * p3) >> 8) + ((var1 * p2) << 12)
    var1 = (((1 << 47) + var1) * p1) >> 33
    if var1 == 0:
        return 0
    p = 1048576 - adc_p
    num = ((p << 31) - var2) * 3125
    p = abs(num) // abs(var1) * (1 if (num < 0) == (var1 < 0) else -1)   # C: toward zero
    var1 = (p9 * (p >> 13) * (p >> 13)) >> 25
    var2 = (p8 * p) >> 19
    return ((p + var1 + var2) >> 8) + (p7 << 4)


@dataclass(frozen=True)
class Reading:
    """One compensated measurement."""

    pressure: float | None   # [Pa], None when the pressure measurement was skipped
    temperature: float       # [degC]


def compensate(adc_p: int, adc_t: int, cal: Calibration) -> Reading:
    """Return the pressure [Pa] and temperature [degC] of one burst's raw values."""
    fine = t_fine(adc_t, cal)
    pressure = None if adc_p == SKIPPED else pressure_q24_8(adc_p, fine, cal) / 256.0
    return Reading(pressure, temperature_centi(fine) / 100.0)
