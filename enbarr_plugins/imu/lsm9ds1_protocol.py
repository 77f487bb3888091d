"""ST LSM9DS1 over I2C: register addresses, bits, codes and sensitivities.

The numbers of the driver (``lsm9ds1.py``), each from ST DocID025715 "LSM9DS1 iNEMO inertial
module" Rev 3: Table 3 (sensitivities), the register map (section 6) and the register
descriptions (sections 7 and 8). Cross-checked with ST's reference driver
(STMicroelectronics/STMems_Standard_C_drivers ``lsm9ds1_STdC/driver/lsm9ds1_reg.h`` and
``lsm9ds1_reg.c``: register addresses, bit fields, ``lsm9ds1_from_fs*_to_*`` factors) and
Linux (``drivers/iio/imu/st_lsm6dsx/st_lsm6dsx_core.c``, the LSM9DS1 entry;
``drivers/iio/magnetometer/st_magn_core.c``).
``test/plugins/imu/test_lsm9ds1_protocol.py`` pins every number here to the same sources; the
emulator keeps its own copy (``lsm9ds1_emulator.py``) so that neither can hide the other's
mistake.

Magnetometer sensitivity: Table 3 gives 0.14, 0.29, 0.43 and 0.58 mgauss/LSB at +-4, 8, 12 and
16 gauss (typical), and ST's reference driver uses the same factors
(``lsm9ds1_from_fs4gauss_to_mG`` ... ``fs16gauss``). Linux uses 146, 292, 438 and 584
ugauss/LSB: st_magn_core.c serves the LSM9DS1 magnetometer with the settings entry of the
LIS3MDL (the same magnetometer; its own data sheet gives 6842 LSB/gauss at +-4 gauss, and
1/6842 gauss = 0.146 mgauss). This driver follows the LSM9DS1's data sheet. With Linux's
factor every field magnitude reads 4.3 % higher at +-4 gauss; a heading does not change.
Either is a typical value of the part: calibrate the unit's magnetometer (hard and soft iron).

Two I2C devices in one package: accelerometer + gyroscope at 0x6B (0x6A with SDO_AG low),
magnetometer at 0x1E (0x1C with SDO_M low); each has WHO_AM_I at 0x0F.
"""

from __future__ import annotations

import numpy as np

# -- accelerometer + gyroscope device -----------------------------------------------------------
ADDRESS_AG = 0x6B
WHO_AM_I = 0x0F            # both devices
WHO_AM_I_AG_VALUE = 0x68
CTRL_REG1_G = 0x10         # ODR_G [7:5], FS_G [4:3]
STATUS_REG_G = 0x17        # XLDA bit 0, GDA bit 1 (mirrored at STATUS_REG)
OUT_X_L_G = 0x18           # gyro X, Y, Z: 16-bit little-endian
CTRL_REG4 = 0x1E           # Zen_G, Yen_G, Xen_G: bits 5:3
CTRL_REG5_XL = 0x1F        # Zen_XL, Yen_XL, Xen_XL: bits 5:3
CTRL_REG6_XL = 0x20        # ODR_XL [7:5], FS_XL [4:3]
CTRL_REG8 = 0x22           # BOOT 7, BDU 6, ..., IF_ADD_INC 2, BLE 1, SW_RESET 0
STATUS_REG = 0x27
OUT_X_L_XL = 0x28          # accel X, Y, Z: 16-bit little-endian
XLDA, GDA = 0x01, 0x02
BDU, IF_ADD_INC = 0x40, 0x04
XYZ_ENABLED = 0x38         # the three axis enable bits of CTRL_REG4 / CTRL_REG5_XL

# -- magnetometer device ------------------------------------------------------------------------
ADDRESS_M = 0x1E
WHO_AM_I_M_VALUE = 0x3D
CTRL_REG1_M = 0x20         # TEMP_COMP 7, OM [6:5], DO [4:2]
CTRL_REG2_M = 0x21         # FS [6:5]
CTRL_REG3_M = 0x22         # MD [1:0]: 0 continuous, 3 power-down (power-on)
CTRL_REG4_M = 0x23         # OMZ [3:2]
CTRL_REG5_M = 0x24         # BDU bit 6
STATUS_REG_M = 0x27        # ZYXDA bit 3
OUT_X_L_M = 0x28           # X, Y, Z: 16-bit little-endian
ZYXDA = 0x08
OM_ULTRA_HIGH = 0x3        # OM / OMZ: ultra-high performance
MD_CONTINUOUS = 0x0
#: MSB of the magnetometer's sub-address: the burst auto-increments (Linux st_magn's
#: ``multi_read_bit``); without it every byte repeats the register.
AUTO_INCREMENT_M = 0x80

#: Accelerometer/gyroscope output data rate [Hz] -> ODR_G code (ODR_XL takes the same code;
#: with the gyroscope on, the accelerometer runs at the gyroscope's rate).
GYRO_ODR = {14.9: 1, 59.5: 2, 119.0: 3, 238.0: 4, 476.0: 5, 952.0: 6}
#: Gyroscope full scale [dps] -> (FS_G code, sensitivity [dps/LSB]); Table 3 G_So.
GYRO_RANGE = {245.0: (0, 8.75e-3), 500.0: (1, 17.50e-3), 2000.0: (3, 70e-3)}
#: Accelerometer full scale [g] -> (FS_XL code, sensitivity [g/LSB]); Table 3 LA_So.
ACCEL_RANGE = {2.0: (0, 0.061e-3), 4.0: (2, 0.122e-3), 8.0: (3, 0.244e-3),
               16.0: (1, 0.732e-3)}
#: Magnetometer output data rate [Hz] -> DO code.
MAG_ODR = {0.625: 0, 1.25: 1, 2.5: 2, 5.0: 3, 10.0: 4, 20.0: 5, 40.0: 6, 80.0: 7}
#: Magnetometer full scale [gauss] -> (FS code, sensitivity [gauss/LSB]); Table 3 M_GN (see
#: the module docstring for Linux's 0.146).
MAG_RANGE = {4.0: (0, 0.14e-3), 8.0: (1, 0.29e-3), 12.0: (2, 0.43e-3), 16.0: (3, 0.58e-3)}
GAUSS = 1e-4  # [T]

#: Magnetometer axes -> the accelerometer/gyroscope axes (the data sheet's figure of the
#: axes beside the pin 1 indicator): X_M points opposite X_AG, Y and Z agree (``lsm9ds1.py``).
MAG_AXES = np.array([-1.0, 1.0, 1.0])
