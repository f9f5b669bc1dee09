"""Sample-clock error from host timestamps (the `clock` effect is not visible in static means)."""

from __future__ import annotations

import numpy as np

from accellog.core.errors import InputError


def clock_from_host_time(t_sensor_s: np.ndarray, t_host_s: np.ndarray) -> dict:
    """Sample-clock error from host timestamps: t_host = (1 + eps_clock) t_sensor + c + jitter.

    Host time is often stamped per read batch (every sample of a batch carries the batch's read
    time), so only the last sample of each run of equal host times is used.
    Returns eps_clock (1), its 1-sigma (from the residual scatter) and ppm values."""
    ts = np.asarray(t_sensor_s, float)
    th = np.asarray(t_host_s, float)
    last = np.flatnonzero(np.append(np.diff(th) != 0, True))
    ts, th = ts[last], th[last]
    if ts.size < 3 or np.ptp(ts) <= 0:
        raise InputError("host time needs >= 3 samples over a non-zero time span")
    A = np.stack([ts - ts.mean(), np.ones_like(ts)], axis=1)
    coef, *_ = np.linalg.lstsq(A, th, rcond=None)
    res = th - A @ coef
    s2 = float(res @ res) / max(ts.size - 2, 1)
    sig = float(np.sqrt(s2 / np.sum((ts - ts.mean()) ** 2)))
    eps = float(coef[0] - 1.0)
    return {"eps_clock": eps, "sigma": sig, "eps_ppm": eps * 1e6, "sigma_ppm": sig * 1e6}
