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

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from .errors import InputError
from .integrate import displacement
from .noise import integrated_autocorr_time

if TYPE_CHECKING:
    from .calibration import Calibration
    from .session import Session

LIMITS = (
    "residual-bias model for a sensor at rest in the fitted orientation: invalid once the sensor "
    "moves or turns; extrapolates poorly beyond the fitted duration; uncertainties assume white "
    "(autocorrelation-inflated) acceleration noise only"
)
AXES = ("x", "y", "z")


@dataclass
class DriftModel:
    """q (3 axes x [q0 m, q1 m/s, q2 m/s^2]) with covariance per axis (3,3,3)."""

    q: np.ndarray  # (3,3): rows x,y,z; columns q0 (m), q1 (m/s), q2 (m/s^2)
    cov: np.ndarray  # (3,3,3): per axis covariance of (q0, q1, q2)
    fit_duration_s: float
    up_sensor: tuple[float, float, float] | None = None
    source: str = ""
    rms_residual_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    limits: str = LIMITS

    @property
    def sigma(self) -> np.ndarray:
        """(3,3) standard deviations of q (same layout as q)."""
        return np.sqrt(np.maximum(np.diagonal(self.cov, axis1=1, axis2=2), 0.0))

    def predict(self, t_s: np.ndarray) -> np.ndarray:
        """(n,3) drift 1/2 q2 t^2 + q1 t + q0 (m)."""
        t = np.asarray(t_s, float)[:, None]
        return 0.5 * self.q[:, 2] * t**2 + self.q[:, 1] * t + self.q[:, 0]

    def apply(self, t_s: np.ndarray, disp_m: np.ndarray) -> np.ndarray:
        """Corrected displacement d = d' - (1/2 q2 t^2 + q1 t + q0) (m)."""
        return np.asarray(disp_m, float) - self.predict(t_s)

    def to_dict(self) -> dict:
        return {
            "equation": "d' = d + 1/2 q2 t^2 + q1 t + q0 (per axis; t s since session start)",
            "units": {"q0": "m", "q1": "m/s", "q2": "m/s^2"},
            "axes": {
                ax: {
                    "q0_m": float(self.q[i, 0]),
                    "q1_mps": float(self.q[i, 1]),
                    "q2_mps2": float(self.q[i, 2]),
                    "sigma_q0_m": float(self.sigma[i, 0]),
                    "sigma_q1_mps": float(self.sigma[i, 1]),
                    "sigma_q2_mps2": float(self.sigma[i, 2]),
                    "rms_residual_m": float(self.rms_residual_m[i]),
                }
                for i, ax in enumerate(AXES)
            },
            "covariance": self.cov.tolist(),
            "fit_duration_s": self.fit_duration_s,
            "up_sensor": list(self.up_sensor) if self.up_sensor is not None else None,
            "source": self.source,
            "limits": self.limits,
        }

    @classmethod
    def from_dict(cls, d: dict, where: str | None = None) -> DriftModel:
        try:
            q = np.array([[d["axes"][ax][k] for k in ("q0_m", "q1_mps", "q2_mps2")] for ax in AXES], float)
            cov = np.asarray(d.get("covariance", np.zeros((3, 3, 3))), float)
            rms = np.array([d["axes"][ax].get("rms_residual_m", 0.0) for ax in AXES], float)
            up = d.get("up_sensor")
            if cov.shape != (3, 3, 3):
                raise ValueError(f"covariance shape {cov.shape}, expected (3, 3, 3)")
            return cls(
                q=q,
                cov=cov,
                fit_duration_s=float(d["fit_duration_s"]),
                up_sensor=tuple(up) if up is not None else None,
                source=str(d.get("source", "")),
                rms_residual_m=rms,
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"malformed drift model: {exc}", where=where) from exc


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
    import dataclasses

    from .evaluate import calibrated_residual

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
