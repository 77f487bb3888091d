"""Unit tests: the MS5837-30BA's numbers, pinned to the data sheet, and the byte protocol.

Every number below is typed from the sources, never read from the code under test:
- TE Connectivity MS5837-30BA data sheet REV C2 12/2019: figure 1 (commands: reset 0x1E,
  convert D1 0x40..0x48 and D2 0x50..0x58 for OSR 256..4096, ADC read 0x00, PROM read
  0xA0..0xAC), "Version PROM Word 0 programming" (bits 11:5 = 0011010 for the 30BA), figure 9
  and its worked example (C1..C6 = 34982, 36352, 20328, 22354, 26646, 26146; D1 = 4958179,
  D2 = 6815414 -> dT = -5962, TEMP = 1981, SENS = 1145816755, P = 39998), the second-order
  compensation (low temperature: Ti = 3 dT^2 / 2^33, OFFi = 3 (TEMP-2000)^2 / 2, SENSi =
  5 (TEMP-2000)^2 / 2^3; below -15 degC OFFi += 7 (TEMP+1500)^2, SENSi += 4 (TEMP+1500)^2;
  high: Ti = 2 dT^2 / 2^37, OFFi = (TEMP-2000)^2 / 2^4, SENSi = 0) and the conversion
  sequence (an ADC read before the conversion finished returns 0).
- A PROM word 0 of the example calibration with a valid CRC-4, 0x9340 (CRC 9, product 0x1A),
  from an independent MS5837 driver's test; Blue Robotics' ms5837-python (``_crc4``).
"""

from __future__ import annotations

import numpy as np
import pytest

from enbarr_plugins.pressure import ms5837_protocol as proto
from enbarr_plugins.pressure.ms5837_emulator import Ms5837Chip, temp_and_p
from enbarr_plugins.transport.i2c import FakeI2cBus, I2cDevice

EXAMPLE_C = (34982, 36352, 20328, 22354, 26646, 26146)
EXAMPLE_D1, EXAMPLE_D2 = 4958179, 6815414
EXAMPLE_PROM = [0x9340, *EXAMPLE_C]
D1_COMMANDS = {256: 0x40, 512: 0x42, 1024: 0x44, 2048: 0x46, 4096: 0x48}
D2_COMMANDS = {256: 0x50, 512: 0x52, 1024: 0x54, 2048: 0x56, 4096: 0x58}
#: Longest conversion time [ms] per OSR (the MS58xx family's ADC table).
# The driver's waits: TE Connectivity's MS5837_Arduino_Library, ms5837.h
# (MS5837_CONVERSION_TIME_OSR_256 .. _4096), typed again.
CONVERSION_MS = {256: 1.0, 512: 2.0, 1024: 3.0, 2048: 5.0, 4096: 9.0}


def example() -> proto.Calibration:
    return proto.Calibration(*EXAMPLE_C)


# -- numbers --------------------------------------------------------------------------------

def test_commands_are_the_data_sheets():
    assert proto.ADDRESS == 0x76
    assert proto.RESET == 0x1E
    assert proto.ADC_READ == 0x00
    assert proto.PROM_READ == 0xA0
    assert proto.PRODUCT_30BA == 0b0011010
    for osr in D1_COMMANDS:
        assert proto.convert_command(True, osr) == D1_COMMANDS[osr]
        assert proto.convert_command(False, osr) == D2_COMMANDS[osr]
    assert set(proto.OSR) == set(CONVERSION_MS)  # REV C2 has no OSR 8192
    for osr, ms in CONVERSION_MS.items():
        assert proto.OSR[osr][1] == pytest.approx(ms * 1e-3)


def test_osr_8192_is_refused_naming_the_allowed_set():
    with pytest.raises(ValueError, match='osr: 8192 is not one of .*256, 512, 1024, 2048, '
                                         '4096'):
        proto.convert_command(True, 8192)


def test_worked_example_first_order():
    r = proto.compensate(example(), EXAMPLE_D1, EXAMPLE_D2)
    assert r.d_t == -5962
    assert r.temp1 == 1981
    assert r.p1 == 39998


def test_worked_example_second_order():
    # TEMP = 1981 < 2000: the low-temperature branch. (TEMP - 2000)^2 = 361:
    # Ti = 3 * 5962^2 / 2^33 = 0.012 -> 0; OFFi = 3 * 361 / 2 = 541.5 -> 541;
    # SENSi = 5 * 361 / 8 = 225.6 -> 225. P stays 39998 (3999.8 mbar), TEMP 1981 (19.81 degC).
    r = proto.compensate(example(), EXAMPLE_D1, EXAMPLE_D2)
    assert (r.ti, r.offi, r.sensi) == (0, 541, 225)
    assert r.temp == 1981
    assert r.p == 39998
    assert r.pressure_pa == pytest.approx(399980.0)
    assert r.temperature_c == pytest.approx(19.81)


# D2 values that put the example chip in each branch; the expected corrections are computed
# by hand from the data sheet's formulas (shown), not by the code under test.
def _hand(d2: int) -> tuple[int, int, int, int]:
    d_t = d2 - 26646 * 256
    temp = 2000 + (d_t * 26146) // 2**23
    if temp >= 2000:
        return temp, (2 * d_t * d_t) // 2**37, ((temp - 2000) ** 2) // 16, 0
    ti, offi, sensi = (3 * d_t * d_t) // 2**33, (3 * (temp - 2000) ** 2) // 2, \
        (5 * (temp - 2000) ** 2) // 8
    if temp < -1500:
        offi += 7 * (temp + 1500) ** 2
        sensi += 4 * (temp + 1500) ** 2
    return temp, ti, offi, sensi


@pytest.mark.parametrize('d2, branch_temp', [
    (6821376 + 300000, 'high'),      # TEMP > 2000
    (6821376, 'boundary'),           # dT = 0: TEMP = 2000 exactly, the high branch
    (6821376 - 100000, 'low'),       # 2000 > TEMP > -1500
    (6821376 - 2000000, 'very low'),  # TEMP < -1500
    (6821376 - 1106888, 'low'),       # TEMP -1450: not yet very low
    (6821376 - 1122930, 'low'),       # TEMP -1500 exactly: the very-low branch is < -1500
    (6821376 - 1123250, 'very low'),  # TEMP -1501
])
def test_second_order_branches(d2, branch_temp):
    temp, ti, offi, sensi = _hand(d2)
    r = proto.compensate(example(), EXAMPLE_D1, d2)
    assert (r.temp1, r.ti, r.offi, r.sensi) == (temp, ti, offi, sensi)
    assert r.temp == temp - ti
    if branch_temp == 'boundary':
        assert (temp, ti, offi, sensi) == (2000, 0, 0, 0)
    if branch_temp == 'very low':
        assert temp < -1500 and offi > 3 * (temp - 2000) ** 2 // 2
    if branch_temp == 'low':
        assert -1500 <= temp < 2000 and offi == 3 * (temp - 2000) ** 2 // 2


def test_at_exactly_2000_no_low_temperature_correction():
    # The data sheet's branch is TEMP < 20 degC; at 2000 the high branch gives all zeros.
    r = proto.compensate(example(), EXAMPLE_D1, 26646 * 256)
    assert (r.temp1, r.offi, r.sensi) == (2000, 0, 0)


def test_second_order_low_temperature_threshold_is_2000():
    # dT = -1 gives -1 * 26146 / 2^23 = -0.003 -> floor -1: TEMP 1999, the low branch
    # (OFFi = 3 * 1 / 2 = 1, SENSi = 5 * 1 / 8 = 0).
    r = proto.compensate(example(), EXAMPLE_D1, 26646 * 256 - 1)
    assert (r.temp1, r.offi, r.sensi) == (1999, 1, 0)


def test_crc4_of_the_example_prom_is_9():
    assert proto.crc4(EXAMPLE_PROM) == 0x9
    assert proto.crc4([0x0340, *EXAMPLE_C]) == 0x9  # the CRC field itself does not count


def test_crc4_catches_every_single_bit_flip():
    for word in range(1, 7):
        for bit in range(16):
            flipped = list(EXAMPLE_PROM)
            flipped[word] ^= 1 << bit
            assert proto.crc4(flipped) != 0x9, (word, bit)


def test_prom_parsing_returns_c1_to_c6():
    cal = proto.parse_prom(EXAMPLE_PROM, 'i2c-1 0x76')
    assert cal.coefficients == EXAMPLE_C
    assert cal.product == 0x1A


def test_prom_crc_mismatch_is_refused_naming_device_and_words():
    bad = list(EXAMPLE_PROM)
    bad[3] ^= 0x0100
    with pytest.raises(proto.PromError,
                       match=r'^i2c-1 0x76: PROM CRC-4 mismatch: word 0 holds 0x9, the words '
                             r'give 0x[0-9a-f] \(PROM read: 0x9340 0x88a6 0x8e00 0x4e68 '):
        proto.parse_prom(bad, 'i2c-1 0x76')


def test_prom_of_another_product_is_refused():
    word0 = 0x15 << 5   # not 0x1A
    words = [word0, *EXAMPLE_C]
    words[0] |= proto.crc4(words) << 12
    with pytest.raises(proto.PromError, match='product type 0x15 .* not an MS5837-30BA'):
        proto.parse_prom(words, 'i2c-1 0x76')


def test_depth_in_fresh_and_salt_water():
    # 2 bar absolute, surface at 101325 Pa: 98675 Pa of water.
    # fresh: 98675 / (997 * 9.80665) = 10.0923 m; salt: 98675 / (1029 * 9.80665) = 9.7785 m.
    assert proto.depth(200000.0, 101325.0, 997.0) == pytest.approx(10.09226, abs=1e-4)
    assert proto.depth(200000.0, 101325.0, 1029.0) == pytest.approx(9.77841, abs=1e-4)
    assert proto.depth(101325.0, 101325.0, 997.0) == 0.0
    assert proto.G == 9.80665
    assert (proto.DENSITY_FRESH, proto.DENSITY_SALT) == (997.0, 1029.0)


# -- the emulator, checked against the same typed numbers -----------------------------------

def test_emulator_compensation_matches_the_worked_example():
    assert temp_and_p(EXAMPLE_C, EXAMPLE_D1, EXAMPLE_D2) == (1981, 39998)


class Clock:
    """A hand-driven monotonic clock [ns] for the emulated chip."""

    def __init__(self) -> None:
        self.ns = 1_000_000_000

    def __call__(self) -> int:
        return self.ns


def test_emulator_prom_words_and_crc_on_the_bus():
    bus = FakeI2cBus()
    bus.attach(0x76, Ms5837Chip(EXAMPLE_C))
    dev = I2cDevice(bus, 0x76)
    words = [int.from_bytes(dev.read_block(0xA0 + 2 * i, 2), 'big') for i in range(7)]
    assert words == EXAMPLE_PROM


def test_adc_read_mid_conversion_returns_0_and_spoils_it():
    clock = Clock()
    chip = Ms5837Chip(EXAMPLE_C, pressure=200000.0, temperature=10.0, clock=clock)
    bus = FakeI2cBus()
    bus.attach(0x76, chip)
    dev = I2cDevice(bus, 0x76)
    dev.command(0x48)                                  # D1 at OSR 4096: 9 ms
    clock.ns += 8_900_000                              # 8.9 ms: still converting
    assert dev.read_block(0x00, 3) == b'\0\0\0'
    assert chip.early_reads == 1
    clock.ns += 1_000_000
    assert dev.read_block(0x00, 3) == b'\0\0\0'        # spoiled: no result after all
    dev.command(0x40)                                  # D1 at OSR 256: 1 ms
    clock.ns += 1_000_000
    d1 = int.from_bytes(dev.read_block(0x00, 3), 'big')
    assert d1 != 0
    assert dev.read_block(0x00, 3) == b'\0\0\0'        # read twice: 0


@pytest.mark.parametrize('pressure, temperature', [
    (101325.0, 20.0), (300000.0, 4.5), (150000.0, -20.0), (2_500_000.0, 30.0)])
def test_emulator_raw_values_compensate_to_the_truth(pressure, temperature):
    chip = Ms5837Chip(EXAMPLE_C)
    d1, d2 = chip.raw(pressure, temperature)
    r = proto.compensate(example(), d1, d2)
    assert abs(r.pressure_pa - pressure) <= 10.0        # 0.1 mbar steps
    assert abs(r.temperature_c - temperature) <= 0.01   # 0.01 degC steps


def test_emulator_and_driver_crcs_agree_on_other_calibrations():
    # Two copies of the data sheet's algorithm (the emulator's and the protocol's), pinned
    # together on 0x9340 above; here they must agree on calibrations of other chips too.
    rng = np.random.default_rng(5)
    for _ in range(50):
        c = [int(x) for x in rng.integers(0, 65536, 6)]
        chip = Ms5837Chip(c)
        assert proto.parse_prom(chip.prom, 'i2c-1 0x76').coefficients == tuple(c)
