"""TE Connectivity MS5837-30BA (Blue Robotics Bar30) over I2C: commands and compensation.

Pure: no ROS, no I/O. Every number is from the MS5837-30BA data sheet (TE Connectivity, REV C2
12/2019): the command table (figure 1), "Version PROM Word 0 programming", the pressure and
temperature calculation (figure 9, with its worked example) and the second-order
temperature compensation; cross-checked with Blue Robotics' library
(bluerobotics/ms5837-python ``ms5837.py``: commands, ``_crc4``, the 30BA branch of
``_calculate``). ``test/plugins/pressure/test_ms5837_protocol.py`` pins them to the same
sources, typed in; the emulator keeps its own copy (``ms5837_emulator.py``).

The chip has no registers: five one-byte commands. Reset (0x1E); PROM read 0xA0 + 2 * i
(i = 0..6) answers a 16-bit word MSB first (word 0 holds the CRC-4 in bits 15:12 and the
product type in bits 11:5, C1..C6 follow); convert D1 (pressure) 0x40 + 2 * k and D2
(temperature) 0x50 + 2 * k for OSR = 256 * 2**k, k = 0..4 (REV C2 drops OSR 8192, 0x4A/0x5A,
which the 2015 revision listed); ADC read 0x00 answers 24 bits MSB first, and 0 when read
before the conversion finished or a second time.

Integer arithmetic as the data sheet's recommended types (int64): its divisions by powers
of two are arithmetic shifts (floor), which the worked example's TEMP = 1981 needs (dT * C6 /
2**23 = -18.6 -> -19). The example's OFF is printed as 2381326464; C2 * 2**16 + (C4 * dT) /
2**7 with its own C2, C4 and dT is 2381323464 (a typo in the sheet; P = 39998 either way).
"""

from __future__ import annotations

from dataclasses import dataclass

#: 7-bit I2C address (1110110x); the part has no address pin.
ADDRESS = 0x76
RESET = 0x1E
ADC_READ = 0x00
PROM_READ = 0xA0          # + 2 * word, words 0..6
PROM_WORDS = 7
CONVERT_D1 = 0x40         # + OSR offset: pressure
CONVERT_D2 = 0x50         # + OSR offset: temperature
#: Product type in PROM word 0 bits 11:5 of the 30BA ("MS5837-30BA26": 0b0011010).
PRODUCT_30BA = 0x1A
#: Time the chip needs after a reset to reload its PROM [s] (Blue Robotics waits 10 ms).
RESET_TIME = 0.010

#: OSR -> (command offset, time the driver waits for a conversion [s]). The waits are the
#: manufacturer's own driver's (TE Connectivity, MS5837_Arduino_Library, ms5837.h:
#: MS5837_CONVERSION_TIME_OSR_256 .. _4096 = 1, 2, 3, 5, 9 ms), whole milliseconds at or
#: above the chip's longest conversion; Blue Robotics' library waits 2.5 us * OSR.
OSR = {256: (0x0, 1e-3), 512: (0x2, 2e-3), 1024: (0x4, 3e-3), 2048: (0x6, 5e-3),
       4096: (0x8, 9e-3)}

#: Standard gravity [m/s^2] (depth from pressure).
G = 9.80665
#: Fluid densities [kg/m^3] of the ``fluid_density`` parameter's help (Blue Robotics' values).
DENSITY_FRESH = 997.0
DENSITY_SALT = 1029.0


class PromError(ValueError):
    """The PROM read back does not check (CRC) or is not a 30BA's."""


def convert_command(d1: bool, osr: int) -> int:
    """Return the command byte converting D1 (``d1``) or D2 at ``osr``."""
    if osr not in OSR:
        raise ValueError(f"osr: {osr} is not one of the chip's ({', '.join(map(str, OSR))})")
    return (CONVERT_D1 if d1 else CONVERT_D2) + OSR[osr][0]


def crc4(words: list[int] | tuple[int, ...]) -> int:
    """Return the CRC-4 of the 7 PROM words (the data sheet's algorithm, figure "CRC").

    The CRC field (word 0 bits 15:12) counts as zero and an eighth zero word is appended;
    polynomial x^4 + x + 1 run MSB first over the 16 bytes (0x3000 in the 16-bit remainder).
    """
    if len(words) != PROM_WORDS:
        raise ValueError(f'crc4: expected {PROM_WORDS} words, got {len(words)}')
    prom = [words[0] & 0x0FFF, *words[1:], 0]
    rem = 0
    for i in range(16):
        word = prom[i >> 1]
        rem ^= (word & 0x00FF) if i % 2 else (word >> 8)
        for _ in range(8):
            rem = ((rem << 1) ^ 0x3000) if rem & 0x8000 else (rem << 1)
            rem &= 0xFFFF
    return (rem >> 12) & 0xF


@dataclass(frozen=True)
class Calibration:
    """The factory calibration C1..C6 of one chip (PROM words 1..6) and its product type."""

    c1: int  # pressure sensitivity SENS_T1
    c2: int  # pressure offset OFF_T1
    c3: int  # temperature coefficient of pressure sensitivity TCS
    c4: int  # temperature coefficient of pressure offset TCO
    c5: int  # reference temperature T_REF
    c6: int  # temperature coefficient of the temperature TEMPSENS
    product: int = PRODUCT_30BA

    @property
    def coefficients(self) -> tuple[int, int, int, int, int, int]:
        """C1..C6."""
        return self.c1, self.c2, self.c3, self.c4, self.c5, self.c6


def parse_prom(words: list[int] | tuple[int, ...], device: str) -> Calibration:
    """Return the calibration of the 7 PROM words read from ``device`` (for messages).

    ``PromError`` naming the device and the words read when the CRC-4 does not match (a
    corrupted read, another chip) or the product type is not a 30BA's.
    """
    text = ' '.join(f'0x{w:04x}' for w in words)
    if len(words) != PROM_WORDS:
        raise PromError(f'{device}: PROM read {len(words)} words ({text}), expected 7')
    stored, computed = words[0] >> 12, crc4(words)
    if stored != computed:
        raise PromError(f'{device}: PROM CRC-4 mismatch: word 0 holds 0x{stored:x}, the '
                        f'words give 0x{computed:x} (PROM read: {text}); corrupted read or '
                        'not an MS5837?')
    product = (words[0] >> 5) & 0x7F
    if product != PRODUCT_30BA:
        raise PromError(f'{device}: product type 0x{product:02x} in PROM word 0 '
                        f"(0x{words[0]:04x}) is not an MS5837-30BA's (0x{PRODUCT_30BA:02x}); "
                        'a 02BA needs another compensation')
    c1, c2, c3, c4, c5, c6 = words[1:7]
    return Calibration(c1, c2, c3, c4, c5, c6, product=product)


@dataclass(frozen=True)
class Reading:
    """One compensated reading in the data sheet's units and the intermediate values."""

    temp: int    # [0.01 degC], second order applied
    p: int       # [0.1 mbar] = [10 Pa], second order applied
    d_t: int     # dT
    temp1: int   # first-order TEMP [0.01 degC]
    p1: int      # first-order P [0.1 mbar]
    ti: int      # second-order corrections
    offi: int
    sensi: int

    @property
    def pressure_pa(self) -> float:
        """Pressure [Pa] (0.1 mbar = 10 Pa)."""
        return self.p * 10.0

    @property
    def temperature_c(self) -> float:
        """Temperature [degC]."""
        return self.temp / 100.0


def compensate(cal: Calibration, d1: int, d2: int) -> Reading:
    """Return TEMP and P of raw ``d1`` (pressure) and ``d2`` (temperature).

    The 30BA's first-order calculation (figure 9), then its second-order compensation.
    """
    c1, c2, c3, c4, c5, c6 = cal.coefficients
    d_t = d2 - (c5 << 8)                                 # dT = D2 - C5 * 2^8
    temp = 2000 + ((d_t * c6) >> 23)                     # TEMP = 2000 + dT * C6 / 2^23
    off = (c2 << 16) + ((c4 * d_t) >> 7)                 # OFF = C2 * 2^16 + C4 * dT / 2^7
    sens = (c1 << 15) + ((c3 * d_t) >> 8)                # SENS = C1 * 2^15 + C3 * dT / 2^8
    p1 = (((d1 * sens) >> 21) - off) >> 13               # P = (D1 * SENS / 2^21 - OFF) / 2^13
    if temp < 2000:                                      # low temperature
        ti = (3 * d_t * d_t) >> 33
        offi = (3 * (temp - 2000) ** 2) >> 1
        sensi = (5 * (temp - 2000) ** 2) >> 3
        if temp < -1500:                                 # very low temperature
            offi += 7 * (temp + 1500) ** 2
            sensi += 4 * (temp + 1500) ** 2
    else:                                                # high temperature
        ti = (2 * d_t * d_t) >> 37
        offi = ((temp - 2000) ** 2) >> 4
        sensi = 0
    off2, sens2 = off - offi, sens - sensi
    p2 = (((d1 * sens2) >> 21) - off2) >> 13
    return Reading(temp=temp - ti, p=p2, d_t=d_t, temp1=temp, p1=p1, ti=ti, offi=offi,
                   sensi=sensi)


def depth(pressure: float, surface_pressure: float, density: float) -> float:
    """Return the depth [m] below the surface at ``pressure`` [Pa]: (p - p0) / (rho * g).

    ``surface_pressure`` [Pa] is the pressure at the surface (the zero); ``density``
    [kg/m^3] the water's (997 fresh, 1029 salt).
    """
    return (pressure - surface_pressure) / (density * G)
