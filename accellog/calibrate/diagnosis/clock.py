"""Sample-clock error from host timestamps (the `clock` effect is not visible in static means)."""

from __future__ import annotations

import numpy as np

from accellog.core.errors import InputError
from accellog.core.timeseries import LineFit


def clock_from_host_time(line: LineFit | tuple[np.ndarray, np.ndarray]) -> dict:
    """Sample-clock error from host timestamps: t_host = (1 + eps_clock) t_sensor + c + jitter.

    Host time is often stamped per read batch (every sample of a batch carries the batch's read
    time), so only the last sample of each run of equal host times is used (store.stream.HostClock):
    line is the least-squares line of t_host - t_sensor against t_sensor at those points, so
    eps_clock is its slope. Returns eps_clock (1), its 1-sigma (from the residual scatter:
    sqrt(RSS / (n - 2) / Sxx)) and ppm values. line may also be the (t_sensor_s, t_host_s) sample
    times (s) of a session in memory."""
    if isinstance(line, tuple):
        from accellog.store.stream import HostClock

        fitted = HostClock.of(*line)
        if fitted is None:
            raise InputError("host time needs >= 3 samples over a non-zero time span")
        line = fitted
    if line.count < 3 or not line.spread > 0:
        raise InputError("host time needs >= 3 samples over a non-zero time span")
    s2 = line.residual_ss / max(line.count - 2, 1)
    sig = float(np.sqrt(s2 / line.spread))
    eps = float(line.slope)
    return {"eps_clock": eps, "sigma": sig, "eps_ppm": eps * 1e6, "sigma_ppm": sig * 1e6}
