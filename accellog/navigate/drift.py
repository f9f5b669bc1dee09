"""Displacement-drift model of a calibrated sensor at rest (the seed's 'bonus' second stage).

Per axis, the displacement integrated from calibrated static data is modelled as

    d'(t) = d(t) + 1/2 q2 t^2 + q1 t + q0        (m; t in s since session start)

with q2 a residual acceleration bias (m/s^2), q1 a velocity offset (m/s), q0 an offset (m), fitted by
least squares on d(t) of one static session and subtracted from the displacement of another.

Uncertainties: the displacement residuals are a double integral of noise, so they are strongly
correlated and ordinary least-squares errors are far too small. The covariance reported here is
propagated from white acceleration noise of variance sigma_a^2 per sample (inflated by its
autocorrelation time tau): Cov(d(s), d(t)) = sigma_a^2 tau dt (m^2 M / 2 - m^3 / 6), m = min(s,t),
M = max(s,t), evaluated on a decimated time grid. Bias instability and flicker are not included.

LIMITS (stated in every output): a residual-bias model for a sensor at rest in the orientation it
was fitted in; it is not a calibration of the sensor and is invalid once the sensor moves or turns,
and it extrapolates poorly beyond the fitted duration.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from accellog.calibrate.calibration import Calibration
from accellog.calibrate.drift_model import DriftModel
from accellog.calibrate.noise import integrated_autocorr_time
from accellog.core.errors import InputError
from accellog.core.session import Session
from accellog.navigate.evaluate import calibrated_residual
from accellog.navigate.integrate import displacement


def _design(t: np.ndarray) -> np.ndarray:
    return np.c_[np.ones_like(t), t, 0.5 * t**2]


def _noise_cov_q(t: np.ndarray, accel_noise_var: np.ndarray, n_grid: int = 400) -> np.ndarray:
    """(3,3,3) covariance of the OLS q per axis under white acceleration noise (see module doc)."""
    idx = np.unique(np.linspace(0, t.size - 1, min(n_grid, t.size)).astype(int))
    tg = t[idx] - t[0]
    A = _design(t[idx])
    m = np.minimum.outer(tg, tg)
    M = np.maximum.outer(tg, tg)
    K = m**2 * M / 2.0 - m**3 / 6.0  # s^3: Cov of a double integral of unit white noise density
    P = np.linalg.pinv(A)  # (3, g): OLS operator on the grid
    base = P @ K @ P.T
    return accel_noise_var[:, None, None] * base[None, :, :]


def fit_drift(
    t_s: np.ndarray,
    disp_m: np.ndarray,
    *,
    accel_resid_mps2: np.ndarray | None = None,
    up_sensor: tuple[float, float, float] | None = None,
    source: str = "",
) -> DriftModel:
    """Least-squares q per axis on d(t) = q0 + q1 t + 1/2 q2 t^2 (t_s s, disp_m (n,3) m).

    accel_resid_mps2: the gravity-removed calibrated acceleration (n,3) the displacement came from;
    its variance and autocorrelation time give the uncertainty (white-noise propagation). Without
    it, sigma is NaN (no honest estimate).
    """
    t = np.asarray(t_s, float)
    d = np.asarray(disp_m, float)
    if t.ndim != 1 or t.size < 10 or d.shape != (t.size, 3):
        raise InputError(f"drift fit needs >= 10 samples of (n,3) displacement, got t {t.shape}, d {d.shape}")
    if not (np.isfinite(t).all() and np.isfinite(d).all()):
        raise InputError("drift fit: displacement or time contains NaN")
    A = _design(t)
    coef, *_ = np.linalg.lstsq(A, d, rcond=None)  # (3 params, 3 axes)
    resid = d - A @ coef
    if accel_resid_mps2 is not None:
        a = np.asarray(accel_resid_mps2, float)
        tau = np.asarray(integrated_autocorr_time(a))
        dt = float(np.median(np.diff(t)))
        var_density = a.var(axis=0, ddof=1) * tau * dt  # (m/s^2)^2 s
        cov = _noise_cov_q(t, var_density)
    else:
        cov = np.full((3, 3, 3), np.nan)
    return DriftModel(
        q=coef.T.copy(),
        cov=cov,
        fit_duration_s=float(t[-1] - t[0]),
        up_sensor=up_sensor,
        source=source,
        rms_residual_m=np.sqrt(np.mean(resid**2, axis=0)),
    )


def drift_from_session(
    session: Session,
    cal: Calibration,
    *,
    up_sensor: tuple[float, float, float] | None = None,
    until_s: float | None = None,
    max_samples: int | None = None,
) -> tuple[Calibration, DriftModel]:
    """Fit the drift model on a static session calibrated with `cal`; returns (cal + drift, drift).

    The session is calibrated, gravity is removed (up * g_local), the residual acceleration is
    integrated twice over its timestamps and q is fitted per axis (see fit_drift).
    """

    t, r, up, _, _, _ = calibrated_residual(
        session, cal, up_sensor=up_sensor, until_s=until_s, max_samples=max_samples
    )
    _, d = displacement(t, r, remove_gravity_mps2=None, where=session.path)
    dm = fit_drift(
        t,
        d,
        accel_resid_mps2=r - r.mean(axis=0),
        up_sensor=tuple(float(v) for v in up),
        source=session.path or session.meta.source,
    )
    return dataclasses.replace(cal, drift=dm, path=None), dm
