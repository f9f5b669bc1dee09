"""MPU-9250 (MPU-6500 die) and AK8963 register addresses and bits, shared by driver and emulator.

Sources: RM-MPU-9250A-00 rev 1.6 (register map), PS-MPU-9250A-01 (product spec), AK8963 datasheet;
see /work/shared/reference/mpu9250.md. Accel/temp/gyro data are big-endian int16, AK8963 data are
little-endian int16.
"""

from __future__ import annotations

# -- bus addresses -------------------------------------------------------------------------------
MPU_ADDRESS = 0x68
"""AD0 = 0; 0x69 with AD0 = 1."""
MPU_ADDRESS_ALT = 0x69
AK8963_ADDRESS = 0x0C
"""Answers only in pass-through mode (INT_PIN_CFG.BYPASS_EN = 1 and USER_CTRL.I2C_MST_EN = 0)."""

# -- MPU-9250 registers --------------------------------------------------------------------------
SELF_TEST_X_GYRO = 0x00
SELF_TEST_X_ACCEL = 0x0D
XG_OFFSET_H = 0x13
SMPLRT_DIV = 0x19
CONFIG = 0x1A
GYRO_CONFIG = 0x1B
ACCEL_CONFIG = 0x1C
ACCEL_CONFIG2 = 0x1D
FIFO_EN = 0x23
INT_PIN_CFG = 0x37
INT_ENABLE = 0x38
INT_STATUS = 0x3A
ACCEL_XOUT_H = 0x3B
TEMP_OUT_H = 0x41
GYRO_XOUT_H = 0x43
USER_CTRL = 0x6A
PWR_MGMT_1 = 0x6B
PWR_MGMT_2 = 0x6C
FIFO_COUNTH = 0x72
FIFO_COUNTL = 0x73
FIFO_R_W = 0x74
WHO_AM_I = 0x75
XA_OFFSET_H = 0x77
YA_OFFSET_H = 0x7A
ZA_OFFSET_H = 0x7D

# CONFIG
CONFIG_FIFO_MODE = 0x40
"""1: when full, new data are dropped; 0: the oldest data are overwritten."""
CONFIG_DLPF_MASK = 0x07

# GYRO_CONFIG
GYRO_FS_SHIFT = 3
GYRO_FS_MASK = 0x18
GYRO_FCHOICE_B_MASK = 0x03

# ACCEL_CONFIG / ACCEL_CONFIG2
ACCEL_FS_SHIFT = 3
ACCEL_FS_MASK = 0x18
ACCEL_FCHOICE_B = 0x08
A_DLPF_MASK = 0x07

# FIFO_EN
FIFO_EN_TEMP = 0x80
FIFO_EN_GX = 0x40
FIFO_EN_GY = 0x20
FIFO_EN_GZ = 0x10
FIFO_EN_ACCEL = 0x08
FIFO_EN_ACCEL_TEMP_GYRO = 0xF8
"""ACCEL(6) TEMP(2) GX GY GZ (6): 14-byte packets in register order."""

# INT_PIN_CFG / INT_ENABLE / INT_STATUS
INT_PIN_BYPASS_EN = 0x02
INT_FIFO_OFLOW = 0x10
INT_RAW_DATA_RDY = 0x01

# USER_CTRL
USER_FIFO_EN = 0x40
USER_I2C_MST_EN = 0x20
USER_I2C_IF_DIS = 0x10
USER_FIFO_RST = 0x04
USER_I2C_MST_RST = 0x02
USER_SIG_COND_RST = 0x01

# PWR_MGMT_1
PWR_H_RESET = 0x80
PWR_SLEEP = 0x40
PWR_CYCLE = 0x20
PWR_CLKSEL_PLL = 0x01
PWR_MGMT_1_RESET = 0x01

# WHO_AM_I values
WHO_AM_I_MPU9250 = 0x71
WHO_AM_I_MPU9255 = 0x73
WHO_AM_I_MPU6500 = 0x70
WHO_AM_I_MPU6515 = 0x74
WHO_AM_I_MPU6050 = 0x68

FIFO_SIZE_BYTES = 512
PACKET_BYTES = 14
"""accel xyz + temp + gyro xyz, int16 big-endian each."""

# Sensitivities by full-scale select (FS_SEL 0..3)
ACCEL_RANGES_G = (2, 4, 8, 16)
GYRO_RANGES_DPS = (250, 500, 1000, 2000)

GYRO_DLPF_BANDWIDTH_HZ = (250.0, 184.0, 92.0, 41.0, 20.0, 10.0, 5.0, 3600.0)
"""Gyro/temp -3 dB bandwidth by DLPF_CFG 0..7 (FCHOICE_B = 00), RM 4.6."""
GYRO_DLPF_INTERNAL_HZ = (8000.0, 1000.0, 1000.0, 1000.0, 1000.0, 1000.0, 1000.0, 8000.0)
"""Internal gyro sample rate by DLPF_CFG; SMPLRT_DIV divides it only for DLPF_CFG 1..6."""
GYRO_FCHOICE_BYPASS_BANDWIDTH_HZ = 8800.0
GYRO_FCHOICE_BYPASS_RATE_HZ = 32000.0
ACCEL_DLPF_BANDWIDTH_HZ = (218.1, 218.1, 99.0, 44.8, 21.2, 10.2, 5.05, 420.0)
"""Accel -3 dB bandwidth by A_DLPFCFG 0..7 (accel_fchoice_b = 0), RM 4.8."""
ACCEL_FCHOICE_BYPASS_BANDWIDTH_HZ = 1046.0

# -- AK8963 registers ----------------------------------------------------------------------------
AK_WIA = 0x00
AK_INFO = 0x01
AK_ST1 = 0x02
AK_HXL = 0x03
AK_ST2 = 0x09
AK_CNTL1 = 0x0A
AK_CNTL2 = 0x0B
AK_ASTC = 0x0C
AK_ASAX = 0x10

AK_WIA_VALUE = 0x48
AK_ST1_DRDY = 0x01
AK_ST1_DOR = 0x02
AK_ST2_HOFL = 0x08
AK_ST2_BITM = 0x10
AK_CNTL1_BIT_16 = 0x10
AK_MODE_POWER_DOWN = 0x00
AK_MODE_SINGLE = 0x01
AK_MODE_CONT_8HZ = 0x02
AK_MODE_CONT_100HZ = 0x06
AK_MODE_EXT_TRIG = 0x04
AK_MODE_SELF_TEST = 0x08
AK_MODE_FUSE_ROM = 0x0F
AK_CNTL2_SRST = 0x01
AK_MODE_RATE_HZ = {AK_MODE_CONT_8HZ: 8.0, AK_MODE_CONT_100HZ: 100.0}
AK_HOFL_LIMIT_UT = 4912.0
"""ST2.HOFL is set when |X| + |Y| + |Z| >= 4912 uT."""


def sample_rate_hz(config: int, gyro_config: int, smplrt_div: int) -> float:
    """Output data rate (Hz) of data registers and FIFO for the CONFIG/GYRO_CONFIG/SMPLRT_DIV values.

    FCHOICE_B != 0 -> 32 kHz; DLPF_CFG 0 or 7 -> 8 kHz; DLPF_CFG 1..6 -> 1 kHz / (1 + SMPLRT_DIV).
    """
    if gyro_config & GYRO_FCHOICE_B_MASK:
        return GYRO_FCHOICE_BYPASS_RATE_HZ
    dlpf = config & CONFIG_DLPF_MASK
    if 1 <= dlpf <= 6:
        return GYRO_DLPF_INTERNAL_HZ[dlpf] / (1 + smplrt_div)
    return GYRO_DLPF_INTERNAL_HZ[dlpf]


def gyro_bandwidth_hz(config: int, gyro_config: int) -> float:
    """Gyro -3 dB bandwidth (Hz) for the CONFIG / GYRO_CONFIG values."""
    if gyro_config & GYRO_FCHOICE_B_MASK:
        return GYRO_FCHOICE_BYPASS_BANDWIDTH_HZ
    return GYRO_DLPF_BANDWIDTH_HZ[config & CONFIG_DLPF_MASK]


def accel_bandwidth_hz(accel_config2: int) -> float:
    """Accelerometer -3 dB bandwidth (Hz) for the ACCEL_CONFIG2 value."""
    if accel_config2 & ACCEL_FCHOICE_B:
        return ACCEL_FCHOICE_BYPASS_BANDWIDTH_HZ
    return ACCEL_DLPF_BANDWIDTH_HZ[accel_config2 & A_DLPF_MASK]
