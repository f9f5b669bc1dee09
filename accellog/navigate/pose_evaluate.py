"""Evaluate a calibration on a session with several labelled holds, window by window.

Per window w of every hold: r_w = correct(theta, a'_w) - truth_g(up_w) (g; the raw reading: a'_w -
up_w), chi2 = sum (r_w / sigma_w)^2 against the window noise, per pose the weighted mean and sem, and
per pass / per window what one pose mean hides (navigate.pose_passes). The displacement at 60 s is
per hold, extrapolated from the hold's mean residual as if it persisted from rest:
d_k(60 s) = 1/2 mean_r_k (m/s^2) (60 s)^2.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from accellog.calibrate.calfile.calibration import Calibration
from accellog.calibrate.observe.segment import observations
from accellog.core.jsonio import JsonResult
from accellog.core.session import ObsTable, Session
from accellog.navigate.pose_passes import AXES, PassRow, TrendRow, disagreements, flag_lines, passes, trends


@dataclass
class PoseEvaluation(JsonResult):
    """Window-by-window residuals of a calibration on a multi-pose session (g)."""

    label: str
    session: str
    pose_names: list[str]
    mean_resid_g: np.ndarray  # (poses,3)
    sem_g: np.ndarray  # (poses,3)
    rms_g: float
    chi2: float
    dof: int
    mps2_per_unit: float = float("nan")
    """m/s^2 per unit of the evaluated output (calibration's, or g_local for the raw reading)."""
    mean_resid_all_g: np.ndarray | None = None
    """(3,) mean residual over every window of every hold (g)."""
    at_s: float = 60.0
    passes: list[PassRow] = field(default_factory=list)
    """One row per visit of a pose (navigate.pose_passes)."""
    trends: list[TrendRow] = field(default_factory=list)
    """Slopes of each pose's window residuals against temperature and time in the hold."""
    flags: list[str] = field(default_factory=list)
    """Poses whose passes disagree beyond noise or whose windows trend (sentences)."""
    window_resid_g: np.ndarray | None = None
    """(windows,3) residual of every window (g; for plots, not in to_dict)."""

    @property
    def disp_at_m(self) -> np.ndarray:
        """(poses,3) m: per-hold displacement at at_s, 1/2 mean_r (m/s^2) at_s^2 (see module doc)."""
        return 0.5 * self.mean_resid_g * self.mps2_per_unit * self.at_s**2

    def to_dict(self) -> dict:
        d60 = self.disp_at_m
        worst = d60[np.argmax(np.abs(d60), axis=0), np.arange(3)] if d60.size else np.full(3, np.nan)
        mean_all = self.mean_resid_all_g if self.mean_resid_all_g is not None else np.full(3, np.nan)
        return {
            "label": self.label,
            "session": self.session,
            "kind": "poses",
            "poses": {
                n: {
                    "mean_residual_g": m.tolist(),
                    "sem_g": s.tolist(),
                    "mean_residual_mps2": (m * self.mps2_per_unit).tolist(),
                    f"displacement_{self.at_s:g}s_m": d.tolist(),
                }
                for n, m, s, d in zip(self.pose_names, self.mean_resid_g, self.sem_g, d60, strict=True)
            },
            "rms_g": self.rms_g,
            "rms_mps2": self.rms_g * self.mps2_per_unit,
            "mean_residual_mps2": dict(zip(AXES, (mean_all * self.mps2_per_unit).tolist(), strict=True)),
            "chi2": self.chi2,
            "dof": self.dof,
            "chi2_dof": self.chi2 / self.dof if self.dof else None,
            "chi2_noise": self.chi2,
            "chi2_noise_dof": self.chi2 / self.dof if self.dof else None,
            "mps2_per_unit": self.mps2_per_unit,
            f"displacement_{self.at_s:g}s_m": worst.tolist(),
            "displacement_note": f"per hold, extrapolated from rest: 1/2 mean residual ({self.at_s:g} s)^2; "
            "top level: the hold with the largest |d| per axis",
            "passes": [p.to_dict() for p in self.passes],
            "pass_disagreement": {
                k: {"chi2": c, "dof": d, "p_value": p} for k, (c, d, p) in disagreements(self.passes).items()
            },
            "trends": [t.to_dict() for t in self.trends],
            "flags": list(self.flags),
        }


def evaluate_poses(
    session: Session,
    cal: Calibration | None,
    *,
    window_s: float = 2.0,
    trim_s: float = 0.5,
    at_s: float = 60.0,
    local_gravity_mps2: float | None = None,
) -> PoseEvaluation:
    """Residual corrected - truth_g * up per window of every labelled hold; chi2 against sigma_g.

    cal=None: the raw reading against up (truth 1, unit g_local: the seed's "No calibration")."""
    obs = observations(session, window_s=window_s, trim_s=trim_s)
    g = float(local_gravity_mps2 or session.meta.local_gravity_mps2)
    return evaluate_pose_obs(
        obs, cal, at_s=at_s, raw_gravity_mps2=g, session=session.path or session.meta.source
    )


def evaluate_pose_obs(
    obs: ObsTable, cal: Calibration | None, *, at_s: float = 60.0, raw_gravity_mps2: float, session: str
) -> PoseEvaluation:
    """evaluate_poses from the session's observation table (segment.observations, or streamed)."""
    from accellog.calibrate.model.fit import obs_drivers

    if cal is None:
        r = np.asarray(obs.meas_g, float) - np.asarray(obs.up_sensor, float)
        unit = float(raw_gravity_mps2)
    else:
        model = cal.model
        drv = {k: v for k, v in obs_drivers(obs).items() if k in model.required_drivers}
        f = model.correct(cal.theta, obs.meas_g, drv)
        truth = model.truth_g(cal.theta, obs.up_sensor, obs.q_sensor_to_world, cal.truth_g)
        r = f - truth
        unit = cal.mps2_per_unit
    k = len(obs.pose_names)
    mean = np.zeros((k, 3))
    sem = np.zeros((k, 3))
    for i in range(k):  # poses, not samples
        m = obs.pose_id == i
        w = 1.0 / obs.sigma_g[m] ** 2
        mean[i] = np.sum(r[m] * w, axis=0) / np.sum(w, axis=0)
        sem[i] = 1.0 / np.sqrt(np.sum(w, axis=0))
    label = cal.model_spec.get("name", "calibrated") if cal is not None else "no calibration"
    rows, trend_rows = passes(obs, r), trends(obs, r)
    return PoseEvaluation(
        label=label,
        session=session,
        pose_names=list(obs.pose_names),
        mean_resid_g=mean,
        sem_g=sem,
        rms_g=float(np.sqrt(np.mean(r**2))),
        chi2=float(np.sum((r / obs.sigma_g) ** 2)),
        dof=int(r.size),
        mps2_per_unit=float(unit),
        mean_resid_all_g=r.mean(axis=0),
        at_s=float(at_s),
        passes=rows,
        trends=trend_rows,
        flags=flag_lines(rows, trend_rows, label) if cal is not None else [],  # raw: a baseline
        window_resid_g=r,
    )
