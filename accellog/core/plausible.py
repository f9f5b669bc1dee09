"""What an IMU recording can plausibly hold, and which unit mistake explains values that it cannot.

Used at the door (``accellog import csv`` refuses with the likely fix) and by ``accellog doctor``
(reports a defect in a file already written):

- sample rate 1 / median(dt) within RATE_MIN_HZ .. RATE_MAX_HZ (1 Hz .. 100 kHz); outside, the time
  unit u in {s, ms, us, ns} whose rate 1 / (step * u) lies in that range, closest to
  TYPICAL_RATE_HZ on a log scale, is the likely one;
- median |a| at rest ~ 1 g (0.5 .. 2 g): ~9.8 means m/s^2, >= 500 means raw counts at the nearest
  MPU-9250 sensitivity (16384 / 8192 / 4096 / 2048 LSB/g), ~1 g times a power of 2 a full-scale
  mismatch (``accel_scale_guess``: a +-8 g log converted as +-2 g reads 0.25 g);
- gyro: a median |w| above 2000 deg/s (35 rad/s) is beyond any MEMS range; whole numbers with a
  median |w| above GYRO_INT_DPS (or beside accelerometer counts) are raw counts read as deg/s;
- time stamps must fit int64 nanoseconds: |t| < MAX_TIME_S (about 292 years);
- every sample finite, |a| <= MAX_ACCEL_G and |w| <= MAX_GYRO_DPS (no MEMS part measures beyond).
"""

from __future__ import annotations

import math

import numpy as np

from accellog.core.units import ACCEL_LSB_PER_G, STANDARD_GRAVITY_MPS2

RATE_MIN_HZ = 1.0
RATE_MAX_HZ = 1e5
TYPICAL_RATE_HZ = 200.0
"""Centre (log scale) of the rates IMU loggers use; picks between two plausible time units."""
TIME_UNIT_S = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
TIME_UNIT_NAME = {"s": "seconds", "ms": "milliseconds", "us": "microseconds", "ns": "nanoseconds"}
MAX_TIME_S = 9.2e9
"""Largest |t| (s) that int64 nanoseconds hold (2**63 ns = 9.22e9 s), with a margin for rounding."""
MAX_ACCEL_G = 1000.0
"""Largest |a| (g) of one sample on any axis: high-g MEMS parts reach 400 g; 1e300 is a corrupt value."""
MAX_GYRO_DPS = 1e5
"""Largest |w| (deg/s) of one sample on any axis (MEMS gyros reach 4000 deg/s)."""
GYRO_MAX_DPS = 2000.0
GYRO_INT_DPS = 20.0
"""Median |w| (deg/s) above which whole-number gyro values are taken for raw counts."""
GYRO_LSB_HINT = "LSB is 131, 65.5, 32.8 or 16.4 per deg/s for +-250, 500, 1000 or 2000 deg/s"


def rate_ok(rate_hz: float) -> bool:
    """True for a sample rate an IMU can have (RATE_MIN_HZ .. RATE_MAX_HZ)."""
    return RATE_MIN_HZ <= rate_hz <= RATE_MAX_HZ


def likely_time_unit(step: float, declared: str = "s", keep_declared: bool = True) -> str | None:
    """The time unit that makes a median step of ``step`` (in the declared unit) a plausible rate
    (the one closest to TYPICAL_RATE_HZ), None when no unit does; ``declared`` itself if it does
    (unless keep_declared=False: then the best other unit)."""
    if not (step > 0 and math.isfinite(step)):
        return None
    rates = {u: 1.0 / (step * f) for u, f in TIME_UNIT_S.items()}
    if keep_declared and rate_ok(rates[declared]):
        return declared
    ok = [u for u, r in rates.items() if rate_ok(r) and (keep_declared or u != declared)]
    return min(ok, key=lambda u: abs(math.log(rates[u] / TYPICAL_RATE_HZ))) if ok else None


def accel_unit_guess(median_norm: float) -> tuple[str, float | None] | None:
    """('g', None), ('m/s^2', None) or ('counts', LSB/g) for a median |a| at rest given as a bare
    number; None when no unit makes it ~1 g."""
    m = median_norm
    if 0.5 <= m <= 2.0:
        return "g", None
    if 0.5 * STANDARD_GRAVITY_MPS2 <= m <= 2.0 * STANDARD_GRAVITY_MPS2:
        return "m/s^2", None
    if m >= 500:
        return "counts", nearest_accel_lsb(m)
    return None


ACCEL_SCALES = (2.0, 4.0, 8.0, 16.0, 0.5, 0.25, 0.125, 0.0625)
"""Full-scale mismatches: counts of a +-A g range converted with the sensitivity of a +-B g one read
B/A times the truth (a +-8 g log printed with +-2 g's 16384 LSB/g reads 1/4 g at rest)."""


def accel_scale_guess(median_g: float) -> float | None:
    """The factor k in ACCEL_SCALES that makes a median |a| of ``median_g`` (g) read 0.9 .. 1.1 g at
    rest (k * median_g), None when none does."""
    ok = [k for k in ACCEL_SCALES if 0.9 <= k * median_g <= 1.1]
    return min(ok, key=lambda k: abs(math.log(k * median_g))) if ok else None


def nearest_accel_lsb(counts_per_g: float) -> float:
    """The MPU-9250 accelerometer sensitivity (LSB/g) nearest on a log scale to a median |a| in counts."""
    m = max(float(counts_per_g), 1e-9)
    return min(ACCEL_LSB_PER_G.values(), key=lambda v: abs(math.log(m / v)))


def gyro_counts_evidence(w: np.ndarray, accel_counts: bool, to_dps: float = 1.0) -> str | None:
    """Why gyro values (n, 3) taken for deg/s (``to_dps`` = 180/pi for rad/s) look like raw counts, or
    None: a median |w| beyond GYRO_MAX_DPS, or whole numbers only with a median |w| above GYRO_INT_DPS
    (or beside accelerometer counts, not all equal)."""
    w = np.asarray(w, dtype=np.float64)
    w = w[np.all(np.isfinite(w), axis=1)]
    if w.shape[0] < 2:
        return None
    med = float(np.median(np.abs(w))) * to_dps
    if med > GYRO_MAX_DPS:
        return f"have a median magnitude of {med:.4g} deg/s, beyond any MEMS range"
    whole = bool(np.all(w == np.round(w)))
    if whole and (med > GYRO_INT_DPS or (accel_counts and np.ptp(w) > 0)):
        beside = " beside accelerometer counts" if accel_counts else ""
        return f"are whole numbers only (median magnitude {med:.4g} deg/s){beside}"
    return None
