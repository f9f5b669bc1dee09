"""Double integration of acceleration over the recorded (uneven) timestamps.

    v(t) = int_{t0}^{t} a dt,   d(t) = int_{t0}^{t} v dt     (v(t0) = d(t0) = 0)

by the cumulative trapezoid rule on the real sample times t_s (s); never with a fixed dt. Gravity is
removed as a constant sensor-frame vector (m/s^2), which is right only for a sensor at rest (the
seed's convention: a = true * 9.797 m/s^2, minus 9.797 on z for a z-up test).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from accellog.core.errors import InputError
from accellog.core.timeseries import check_time, cumtrapz
from accellog.core.units import STANDARD_GRAVITY_MPS2

DEFAULT_TIMES_S = (10.0, 30.0, 60.0)
"""Times at which the seed reports the integrated displacement (s)."""


def displacement(
    t_s: np.ndarray,
    accel_mps2: np.ndarray,
    *,
    remove_gravity_mps2: Sequence[float] | np.ndarray | None = (0.0, 0.0, STANDARD_GRAVITY_MPS2),
    where: str | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(vel_mps (n,3), disp_m (n,3)): v = cumtrapz(a - g_vec), d = cumtrapz(v) over t_s.

    accel_mps2: (n,3) specific force in m/s^2 (sensor frame); remove_gravity_mps2: the constant
    reading of a perfect sensor at rest in this pose (up * g_local), subtracted first; None keeps a.
    """
    t = np.asarray(t_s, float)
    a = np.asarray(accel_mps2, float)
    check_time(t, where)
    if a.shape[0] != t.shape[0]:
        raise InputError(f"{a.shape[0]} acceleration rows for {t.shape[0]} timestamps", where=where)
    if not np.all(np.isfinite(a)):
        bad = int(np.argmax(~np.isfinite(a).all(axis=-1)))
        raise InputError(f"acceleration is NaN at sample {bad} (t = {t[bad]:.3f} s)", where=where)
    if remove_gravity_mps2 is not None:
        a = a - np.asarray(remove_gravity_mps2, float)
    vel = cumtrapz(t, a)
    disp = cumtrapz(t, vel)
    return vel, disp


def values_at(
    t_s: np.ndarray, y: np.ndarray, times_s: Sequence[float] = DEFAULT_TIMES_S, *, tolerance_s: float = 0.5
) -> tuple[np.ndarray, np.ndarray]:
    """(t_used_s (m,), y_at (m,...)): y linearly interpolated at each requested time.

    A time after the last sample uses the last sample when it lies within tolerance_s of it (the
    seed's "60 s" file ends at 60.00 s or 59.99 s); further out it gives NaN (never extrapolated).
    """
    t = np.asarray(t_s, float)
    y = np.asarray(y, float)
    req = np.asarray(times_s, float)
    used = np.where(req > t[-1], np.where(req - t[-1] <= tolerance_s, t[-1], np.nan), np.maximum(req, t[0]))
    flat = y.reshape(y.shape[0], -1)
    ok = np.isfinite(used)
    out = np.full((req.shape[0], flat.shape[1]), np.nan)
    for j in range(flat.shape[1]):  # 3 columns: not a per-sample loop
        out[ok, j] = np.interp(used[ok], t, flat[:, j])
    return used, out.reshape((req.shape[0], *y.shape[1:]))
