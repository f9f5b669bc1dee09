"""Online correction and double integration, batch by batch (live recording and replay).

For samples i = 0..N-1 with sensor time t_i (s) and reading m_i (g):

    f_i   = correct(m_i, drivers_i)                  (calibrated specific force, calibrated units;
                                                      identity without a calibration)
    a_i   = f_i * mps2_per_unit - up * g_local       (kinematic acceleration, m/s^2, sensor frame;
                                                      a sensor at rest: the seed's "a = true * 9.797,
                                                      minus 9.797 on z"; accellog.navigate.evaluate's residual)
    v_i   = v_{i-1} + dt_i (a_i + a_{i-1}) / 2       (trapezoid, v_0 = v0_mps)
    d_i   = d_{i-1} + dt_i (v_i + v_{i-1}) / 2       (trapezoid, d_0 = d0_m)

The running sums are carried across batches by ``core.timeseries.cumtrapz`` (the same sequential
accumulation order as ``np.cumsum`` over the whole session), so feeding a session batch by batch gives *bit-identical*
numbers to ``scipy.integrate.cumulative_trapezoid(..., initial=0)`` applied twice to the whole
session, i.e. to ``accellog.navigate.integrate.displacement`` and ``accellog.navigate.evaluate`` (see
``integrate_batch``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from accellog.core.errors import InputError
from accellog.core.timeseries import cumtrapz
from accellog.core.units import STANDARD_GRAVITY_MPS2
from accellog.navigate.integrate import displacement

CorrectFn = Callable[[np.ndarray, Mapping[str, np.ndarray]], np.ndarray]
"""correct(meas_g (n,3), drivers {'t_s': (n,), 'temp_degC': (n,), ...}) -> f_g (n,3)."""


@dataclass
class OnlineStep:
    """Result of one batch: calibrated reading (g), acceleration (m/s^2), velocity, displacement."""

    t_s: np.ndarray
    f_g: np.ndarray
    accel_mps2: np.ndarray
    vel_mps: np.ndarray
    disp_m: np.ndarray


class OnlineIntegrator:
    """Incremental trapezoid double integration of (optionally corrected) accelerometer batches.

    up_sensor: unit up vector of the pose at rest (sensor frame; default (0,0,1): z up).
    local_gravity_mps2: g_local (m/s^2) removed along up_sensor. mps2_per_unit: m/s^2 per unit of
    the corrected reading (default g_local: truths of exactly 1, the seed's convention; a
    Calibration gives ``cal.mps2_per_unit`` = g_local / truth_g). correct: optional calibration,
    ``correct(meas_g, drivers) -> f``. ``from_calibration`` sets all of them from a Calibration.
    """

    def __init__(
        self,
        *,
        up_sensor=(0.0, 0.0, 1.0),
        local_gravity_mps2: float = STANDARD_GRAVITY_MPS2,
        mps2_per_unit: float | None = None,
        correct: CorrectFn | None = None,
        v0_mps=(0.0, 0.0, 0.0),
        d0_m=(0.0, 0.0, 0.0),
    ) -> None:
        self.up_sensor = np.asarray(up_sensor, dtype=np.float64).reshape(3)
        self.local_gravity_mps2 = float(local_gravity_mps2)
        self.mps2_per_unit = float(local_gravity_mps2 if mps2_per_unit is None else mps2_per_unit)
        self.gravity_mps2 = self.up_sensor * self.local_gravity_mps2
        self.correct = correct
        self._v0 = np.asarray(v0_mps, dtype=np.float64).reshape(3)
        self._d0 = np.asarray(d0_m, dtype=np.float64).reshape(3)
        self.reset()

    @classmethod
    def from_calibration(cls, cal, *, up_sensor=(0.0, 0.0, 1.0), local_gravity_mps2: float | None = None):
        """Integrator applying an accellog.calibrate.calfile.calibration.Calibration (its correct(), g_local, units)."""
        g = float(local_gravity_mps2 or cal.local_gravity_mps2)
        return cls(
            up_sensor=up_sensor,
            local_gravity_mps2=g,
            mps2_per_unit=g / cal.truth_g,
            correct=lambda m, d: cal.correct(m, d),
        )

    def reset(self) -> None:
        """Forget all samples (start a new session)."""
        self._last: tuple[float, np.ndarray, np.ndarray] | None = None  # (t, a, v) of the last sample
        self._v_acc = self._v0.copy()
        self._d_acc = self._d0.copy()
        self.n = 0

    @property
    def disp_m(self) -> np.ndarray:
        """Displacement (m) at the newest sample."""
        return self._d_acc.copy()

    @property
    def vel_mps(self) -> np.ndarray:
        """Velocity (m/s) at the newest sample."""
        return self._v_acc.copy()

    def push(
        self, t_s: np.ndarray, meas_g: np.ndarray, drivers: Mapping[str, np.ndarray] | None = None
    ) -> OnlineStep:
        """Add a batch (t_s (n,) increasing and after the previous batch, meas_g (n,3) g)."""
        t = np.asarray(t_s, dtype=np.float64).reshape(-1)
        m = np.asarray(meas_g, dtype=np.float64).reshape(-1, 3)
        if t.shape[0] != m.shape[0]:
            raise InputError(f"{t.shape[0]} times for {m.shape[0]} samples")
        if self.correct is not None and t.shape[0]:
            drv = {"t_s": t, **(drivers or {})}
            f = np.asarray(self.correct(m, drv), dtype=np.float64).reshape(-1, 3)
        else:
            f = m
        a = f * self.mps2_per_unit - self.gravity_mps2
        if t.shape[0] == 0:
            e = np.empty((0, 3))
            return OnlineStep(t, f, a, e, e)
        last = self._last
        v = cumtrapz(t, a, self._v_acc, prev=None if last is None else (last[0], last[1]))
        d = cumtrapz(t, v, self._d_acc, prev=None if last is None else (last[0], last[2]))
        self._last = (float(t[-1]), a[-1].copy(), v[-1].copy())
        self._v_acc, self._d_acc = v[-1].copy(), d[-1].copy()
        self.n += t.shape[0]
        return OnlineStep(t, f, a, v, d)


def integrate_batch(
    t_s: np.ndarray,
    meas_g: np.ndarray,
    *,
    up_sensor=(0.0, 0.0, 1.0),
    local_gravity_mps2: float = STANDARD_GRAVITY_MPS2,
    mps2_per_unit: float | None = None,
    correct: CorrectFn | None = None,
    drivers: Mapping[str, np.ndarray] | None = None,
) -> OnlineStep:
    """Whole-session reference: the same equations with accellog.navigate.integrate.displacement
    (scipy cumulative_trapezoid, initial 0)."""

    t = np.asarray(t_s, dtype=np.float64)
    m = np.asarray(meas_g, dtype=np.float64).reshape(-1, 3)
    f = m if correct is None else np.asarray(correct(m, {"t_s": t, **(drivers or {})}), dtype=np.float64)
    unit = float(local_gravity_mps2 if mps2_per_unit is None else mps2_per_unit)
    a = f * unit - np.asarray(up_sensor, dtype=np.float64) * float(local_gravity_mps2)
    v, d = displacement(t, a, remove_gravity_mps2=None)
    return OnlineStep(t, f, a, v, d)
