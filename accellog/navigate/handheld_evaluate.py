"""evaluate on a hand-held session (no pose labels): judged on the automatically detected static
intervals with the orientation-free gravity-norm residual (imu_tk / ArduPilot).

Per window w of a detected interval (window means a'_w, g; standard errors s_w):

    f_w = correct(theta, a'_w, drivers_w)            (calibrated units; raw: f_w = a'_w)
    e_w = |f_w| - g_cal                              (g_cal = the calibration's truth_g; raw: 1 g)
    sigma_w = |(f_w / |f_w|) * s_w|                  (window noise projected on the measured direction)
    chi2 = sum_w (e_w / sigma_w)^2,  dof = number of windows

Per interval: mean e (weighted) +- sem, chi2/dof. What the norm cannot judge without orientations
(a rotation of the sensor frame, the fixture tilt, the sample clock: calibrate.diagnosis.diagnose.NORM_BLIND)
is said in one line, not guessed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from accellog.calibrate.calfile.calibration import Calibration
from accellog.calibrate.diagnosis.diagnose import NORM_BLIND
from accellog.calibrate.model.fit import obs_drivers
from accellog.calibrate.observe.detect import detect_static, with_labels
from accellog.calibrate.observe.segment import observations
from accellog.core.jsonio import JsonResult
from accellog.core.session import ObsTable, Session

CANNOT_JUDGE = (
    "without orientations the gravity norm cannot judge: "
    + "; ".join(f"{k} ({v})" for k, v in NORM_BLIND.items())
    + "; nor a bias or scale error that leaves |f| unchanged in these orientations"
)


@dataclass
class HandheldEvaluation(JsonResult):
    """Gravity-norm residuals of one calibration (or the raw reading) per detected interval (g)."""

    label: str
    session: str
    intervals: list[dict]
    resid_g: np.ndarray
    """(windows,) |f| - g per window."""
    sigma_g: np.ndarray
    interval_id: np.ndarray
    mps2_per_unit: float
    notes: list[str] = field(default_factory=list)

    @property
    def chi2(self) -> float:
        return float(np.sum((self.resid_g / self.sigma_g) ** 2))

    @property
    def dof(self) -> int:
        return int(self.resid_g.size)

    def rows(self) -> list[dict]:
        """Per interval: start, end, windows, mean norm residual +- sem (g), chi2/dof."""
        out = []
        for k, iv in enumerate(self.intervals):
            m = self.interval_id == k
            w = 1.0 / self.sigma_g[m] ** 2
            out.append(
                {
                    **iv,
                    "n_windows": int(m.sum()),
                    "mean_norm_residual_g": float(np.sum(self.resid_g[m] * w) / np.sum(w)),
                    "sem_g": float(1.0 / np.sqrt(np.sum(w))),
                    "chi2_dof": float(np.mean((self.resid_g[m] / self.sigma_g[m]) ** 2)),
                }
            )
        return out

    def to_dict(self) -> dict:
        return {
            "label": self.label,
            "session": self.session,
            "kind": "handheld",
            "residual": "|f| - g per window of the detected static intervals (g)",
            "intervals": self.rows(),
            "rms_g": float(np.sqrt(np.mean(self.resid_g**2))),
            "rms_mps2": float(np.sqrt(np.mean(self.resid_g**2))) * self.mps2_per_unit,
            "chi2": self.chi2,
            "dof": self.dof,
            "chi2_dof": self.chi2 / max(self.dof, 1),
            "mps2_per_unit": self.mps2_per_unit,
            "cannot_judge": CANNOT_JUDGE,
            "notes": list(self.notes),
        }


def detect_intervals(session: Session, *, window_s: float = 1.0) -> tuple[ObsTable, list[dict]]:
    """Static intervals of an unlabelled session (imu_tk's detector, threshold by the most distinct
    orientations; at least 2) cut into 2 s windows; (observations, interval dicts)."""
    rate = (session.n - 1) / max(float(session.t_s[-1] - session.t_s[0]), 1e-12)
    labels = detect_static(session, window_samples=max(3, round(window_s * rate) | 1), min_poses=2)
    obs = observations(with_labels(session, labels), window_s=2.0, trim_s=0.0)
    ivs = [
        {"start_s": p.start_s, "end_s": p.end_s, "up_sensor": [float(x) for x in p.up_sensor]} for p in labels
    ]
    return obs, ivs


def evaluate_handheld(
    obs: ObsTable, intervals: list[dict], cal: Calibration | None, *, session: str, raw_gravity_mps2: float
) -> HandheldEvaluation:
    """The gravity-norm residual of cal (None: the raw reading against 1 g) on the detected windows."""
    meas = np.asarray(obs.meas_g, float)
    if cal is None:
        f, g, unit, label = meas, 1.0, float(raw_gravity_mps2), "no calibration"
    else:
        drv = {k: v for k, v in obs_drivers(obs).items() if k in cal.model.required_drivers}
        f = cal.model.correct(cal.theta, meas, drv)
        g, unit, label = cal.truth_g, cal.mps2_per_unit, cal.model_spec.get("name", "calibrated")
    norm = np.linalg.norm(f, axis=1)
    sigma = np.sqrt(np.sum((f / norm[:, None] * np.asarray(obs.sigma_g, float)) ** 2, axis=1))
    return HandheldEvaluation(
        label, session, intervals, norm - g, sigma, np.asarray(obs.pose_id), float(unit)
    )
