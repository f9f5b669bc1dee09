"""Online stillness detection for guided recording (is the sensor held still on its pose?).

Statistic: over the last ``window_s`` of samples, the largest per-axis standard deviation of the
accelerometer (g) and, when a gyro is present, of the gyro (deg/s). The sensor counts as still
when both are below their thresholds; a pose may be held once it has been still for ``settle_s``.
Standard deviations (not magnitudes) make the test immune to the (unknown) biases. Defaults sit
well above the MPU-9250's noise at 1 kHz (accel ~7 mg rms, gyro ~0.1 deg/s rms) and well below a
hand-held sensor's tremor.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class StillnessDetector:
    """Feed batches in time order with ``update``; read ``still`` and ``still_for_s``."""

    window_s: float = 0.5
    accel_std_max_g: float = 0.02
    gyro_std_max_dps: float = 2.0
    settle_s: float = 1.0
    _t: np.ndarray = field(default_factory=lambda: np.empty(0))
    _a: np.ndarray = field(default_factory=lambda: np.empty((0, 3)))
    _w: np.ndarray | None = None
    still: bool = False
    still_since_s: float | None = None
    last_t_s: float = 0.0
    accel_std_g: float = float("nan")
    gyro_std_dps: float = float("nan")

    def update(self, t_s: np.ndarray, accel_g: np.ndarray, gyro_dps: np.ndarray | None = None) -> bool:
        """Add samples (t_s (n,), accel_g (n,3), gyro_dps (n,3) or None); return the still state."""
        if len(t_s) == 0:
            return self.still
        self._t = np.concatenate([self._t, t_s])
        self._a = np.concatenate([self._a, accel_g])
        if gyro_dps is not None:
            self._w = gyro_dps if self._w is None else np.concatenate([self._w, gyro_dps])
        keep = self._t >= self._t[-1] - self.window_s
        self._t, self._a = self._t[keep], self._a[keep]
        if self._w is not None:
            self._w = self._w[-len(self._t) :]
        self.last_t_s = float(self._t[-1])
        span = self._t[-1] - self._t[0]
        if len(self._t) < 8 or span < 0.8 * self.window_s:
            return self.still
        self.accel_std_g = float(self._a.std(axis=0).max())
        ok = self.accel_std_g <= self.accel_std_max_g
        if self._w is not None:
            self.gyro_std_dps = float(self._w.std(axis=0).max())
            ok = ok and self.gyro_std_dps <= self.gyro_std_max_dps
        if ok and not self.still:
            self.still_since_s = float(self._t[0])
        if not ok:
            self.still_since_s = None
        self.still = ok
        return ok

    @property
    def still_for_s(self) -> float:
        """How long (s of sensor time) the sensor has been still; 0 when moving."""
        if not self.still or self.still_since_s is None:
            return 0.0
        return self.last_t_s - self.still_since_s

    @property
    def settled(self) -> bool:
        """Still for at least settle_s."""
        return self.still_for_s >= self.settle_s
