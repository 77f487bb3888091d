"""NXP FXOS8700CQ (accelerometer + magnetometer) and FXAS21002C (gyroscope) over I2C.

The numbers of the driver (``fxos8700.py``): NXP FXOS8700CQ data sheet Rev 8 (register
descriptions, sections 14 and 15; sensitivities in the mechanical characteristics) and NXP
FXAS21002C data sheet Rev 2.1 (section 13; sensitivities in the mechanical
characteristics). Cross-checked with Linux (``drivers/iio/imu/fxos8700_core.c``: register
map, WHO_AM_I 0xC7, accelerometer scales 244/488/976 ug; ``drivers/iio/gyro/fxas21002c.h``
and ``fxas21002c_core.c``: register fields, chip ID 0xD7, 62 ms standby -> active) and the
Adafruit libraries (``Adafruit_FXOS8700``: ACCEL_MG_LSB_2G/4G/8G 0.000244/0.000488/0.000976,
MAG_UT_LSB 0.1; ``Adafruit_FXAS21002C``: GYRO_SENSITIVITY_250DPS ... 2000DPS 0.0078125 ...
0.0625 dps/LSB; the same configuration writes: CTRL_REG2 0x02, M_CTRL_REG1 0x1F,
M_CTRL_REG2 0x20, CTRL_REG1 0x15 = 100 Hz hybrid, low noise, active).
``test/plugins/imu/test_fxos8700_protocol.py`` pins every number here to those sources; the
emulator keeps its own copy (``fxos8700_emulator.py``).
"""

from __future__ import annotations

# -- FXOS8700CQ (0x1C..0x1F by SA0/SA1; 0x1F on the Adafruit board) -----------------------------
ADDRESS = 0x1F
STATUS = 0x00               # DR_STATUS with the FIFO off: ZYXDR bit 3
OUT_X_MSB = 0x01            # accel X, Y, Z: 14-bit left-justified, big-endian
FXOS_WHO_AM_I = 0x0D
FXOS_WHO_AM_I_VALUE = 0xC7
XYZ_DATA_CFG = 0x0E         # FS [1:0]
CTRL_REG1 = 0x2A            # DR [5:3], LNOISE bit 2, ACTIVE bit 0; the rest only in standby
CTRL_REG2 = 0x2B            # RST bit 6, MODS [1:0]
M_DR_STATUS = 0x32
M_OUT_X_MSB = 0x33          # magnetometer X, Y, Z: 16-bit big-endian
M_CTRL_REG1 = 0x5B          # M_OS [4:2], M_HMS [1:0]
M_CTRL_REG2 = 0x5C          # HYB_AUTOINC_MODE bit 5
ACTIVE, LNOISE = 0x01, 0x04
MODS_HIGH_RESOLUTION = 0x02
M_HYBRID_OS7 = 0x1F         # M_OS = 7, M_HMS = 3 (hybrid: accelerometer and magnetometer)
#: With it a burst goes on from 0x06 to 0x33: one 13-byte read from STATUS returns status,
#: accelerometer and magnetometer.
HYB_AUTOINC_MODE = 0x20
ZYXDR = 0x08
MAG_LSB = 0.1e-6            # [T] (0.1 uT/LSB, fixed +-1200 uT)

# -- FXAS21002C (0x20 or 0x21 by SA0; 0x21 on the Adafruit board) ------------------------------
GYRO_ADDRESS = 0x21
FXAS_WHO_AM_I = 0x0C
FXAS_WHO_AM_I_VALUE = 0xD7
CTRL_REG0 = 0x0D            # FS [1:0]
G_CTRL_REG1 = 0x13          # RST bit 6, DR [4:2], ACTIVE bit 1, READY bit 0
G_CTRL_REG3 = 0x15          # WRAPTOONE bit 3
G_ACTIVE = 0x02
WRAPTOONE = 0x08

#: Hybrid-mode ODR [Hz] -> CTRL_REG1 DR code (hybrid mode halves the single-sensor rates
#: 800 ... 1.5625 Hz).
ACCEL_ODR = {400.0: 0, 200.0: 1, 100.0: 2, 50.0: 3, 25.0: 4, 6.25: 5, 3.125: 6, 0.7813: 7}
#: Accelerometer full scale [g] -> (FS code, sensitivity [g/LSB] of the 14-bit value).
ACCEL_RANGE = {2.0: (0, 0.244e-3), 4.0: (1, 0.488e-3), 8.0: (2, 0.976e-3)}
#: Gyro ODR [Hz] -> CTRL_REG1 DR code.
GYRO_ODR = {800.0: 0, 400.0: 1, 200.0: 2, 100.0: 3, 50.0: 4, 25.0: 5, 12.5: 6}
#: Gyro full scale [dps] -> (FS code, sensitivity [dps/LSB]).
GYRO_RANGE = {2000.0: (0, 62.5e-3), 1000.0: (1, 31.25e-3), 500.0: (2, 15.625e-3),
              250.0: (3, 7.8125e-3)}
