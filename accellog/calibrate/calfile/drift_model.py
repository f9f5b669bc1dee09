"""The displacement-drift polynomial a calibration file may carry (fitted by accellog.navigate.drift).

    d'(t) = d(t) + 1/2 q2 t^2 + q1 t + q0        (m; t in s since session start)

q2 a residual acceleration bias (m/s^2), q1 a velocity offset (m/s), q0 an offset (m), each axis with
its (3,3) covariance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from accellog.core.errors import InputError

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
            if not (np.isfinite(q).all() and 0 < float(d["fit_duration_s"]) < math.inf):  # cov may be unknown
                raise ValueError("coefficients q0, q1, q2 and fit_duration_s (> 0) must be finite numbers")
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
