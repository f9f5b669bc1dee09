"""Physical constants and unit conversions shared by every stage.

Conventions (used everywhere in accellog):
- acceleration in the models is the *specific force* an accelerometer measures, in g
  (1 g = STANDARD_GRAVITY_MPS2 m/s^2 for count conversions); at rest with +z up a perfect sensor
  reads (0, 0, +1) g;
- the calibration models take the true reading as ``local_gravity_g`` times the pose's up vector,
  where local_gravity_g = local_gravity_mps2 / STANDARD_GRAVITY_MPS2 by default, or exactly 1 g
  for the seed's convention (truth = +-1 g); integration multiplies by the local gravity in m/s^2;
- time in s (float64) in memory, int64 ns in files; temperature in degC; angular rate in deg/s.
"""

from __future__ import annotations

STANDARD_GRAVITY_MPS2 = 9.80665
"""Conventional standard gravity g0 (m/s^2); the chip's LSB/g scale refers to it."""

EARTH_GRAVITY_RANGE_MPS2 = (9.7, 9.9)
"""Local gravity anywhere on Earth's surface (m/s^2): poles 9.83, equator 9.78, altitude lowers it."""

SEED_LOCAL_GRAVITY_MPS2 = 9.797
"""Local gravity used by the capstone study (Conway, Arkansas), m/s^2."""

ACCEL_LSB_PER_G = {2: 16384.0, 4: 8192.0, 8: 4096.0, 16: 2048.0}
"""MPU-9250 accelerometer sensitivity by full scale (+-g -> counts per g), PS Table 2."""

GYRO_LSB_PER_DPS = {250: 131.0, 500: 65.5, 1000: 32.8, 2000: 16.4}
"""MPU-9250 gyro sensitivity by full scale (+-deg/s -> counts per deg/s), PS Table 1."""

TEMP_LSB_PER_DEGC = 333.87
TEMP_OFFSET_DEGC = 21.0
"""TEMP_degC = TEMP_OUT / 333.87 + 21 (RoomTemp_Offset = 0), RM 4.23."""

MAG_UT_PER_LSB_16BIT = 0.15
MAG_UT_PER_LSB_14BIT = 0.6


def temp_counts_to_degC(counts, out=None):
    """Die temperature (degC) = counts / TEMP_LSB_PER_DEGC + TEMP_OFFSET_DEGC from TEMP_OUT counts;
    with ``out`` (float64 array) the same two operations in place, no temporaries."""
    if out is None:
        return counts / TEMP_LSB_PER_DEGC + TEMP_OFFSET_DEGC
    import numpy as np  # the in-place form only (this module stays importable without numpy)

    np.divide(counts, TEMP_LSB_PER_DEGC, out=out)
    np.add(out, TEMP_OFFSET_DEGC, out=out)
    return out


def degC_to_temp_counts(deg_c):
    """TEMP_OUT counts (float, unrounded) for a die temperature in degC."""
    return (deg_c - TEMP_OFFSET_DEGC) * TEMP_LSB_PER_DEGC
