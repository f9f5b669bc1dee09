"""The results of evaluating a calibration window by window (g): per labelled pose, pass and window
(``PoseEvaluation``), or per detected static interval of a hand-held session (``HandheldEvaluation``).

Labelled holds. Per window w: r_w = correct(theta, a'_w) - truth_g(up_w) (raw: a'_w - up_w), chi2 =
sum (r_w / s_w)^2 against the window noise s_w, per pose the weighted mean and sem. The displacement
at 60 s is per hold, extrapolated from the hold's mean residual as if it persisted from rest:
d_k(60 s) = 1/2 mean_r_k (m/s^2) (60 s)^2. A pass is one visit of a pose (consecutive windows of the
same pose; a pose visited while heating and again while cooling has two):

    pass mean     m_p = sum(r_w / s_w^2) / sum(1 / s_w^2),   sem_p = (sum 1 / s_w^2)^-1/2
    pass chi2/dof = sum_w,axes (r_w / s_w)^2 / (3 n_w)          (against the model's zero)
    disagreement  chi2_P = sum_p,axes ((m_p - m_pose) / sem_p)^2, dof 3 (P - 1),
                  m_pose the weighted mean of the passes; flagged when p = Q(chi2_P | dof) < ALPHA
    trend         weighted straight line r_w = a + c x_w per axis and pose, x = temperature (degC) or
                  time in the hold (s); sigma_c from the weights, inflated by sqrt(chi2/dof) of the
                  line when above 1 (windows scatter beyond their noise); flagged when |c| > Z_TREND
                  sigma_c (and the driver spans a range)

Window residuals are treated as independent (the window sigma is autocorrelation-aware within a
window, not across windows). The calibration's own uncertainty is not included: a long test session
can flag a calibration whose temperature term is off by a few of its sigmas where it extrapolates
beyond the calibration's temperature range (that is a real disagreement, not noise).

Hand-held (no pose labels; imu_tk / ArduPilot): per window w of a detected interval (means a'_w, g;
standard errors s_w), f_w = correct(theta, a'_w, drivers_w) (raw: a'_w), e_w = |f_w| - g_cal (the
calibration's truth_g; raw: 1 g), sigma_w = |(f_w / |f_w|) * s_w|, chi2 = sum_w (e_w / sigma_w)^2,
dof = number of windows; per interval the weighted mean e +- sem and chi2/dof. What the norm cannot
judge without orientations (CANNOT_JUDGE) is said in one line, not guessed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from accellog.calibrate.model.effects import NORM_BLIND
from accellog.core.jsonio import JsonResult
from accellog.core.session import ObsTable

AXES = ("x", "y", "z")
ALPHA = 1e-3
"""False-alarm probability of the pass-disagreement test per pose."""
Z_TREND = 5.0
"""A slope is flagged beyond this many (inflated) sigma."""
MIN_SPAN = {"temp_degC": 0.2, "t_in_pose_s": 2.0}
"""Smallest driver range (degC, s) over a pose's windows for a slope to be fitted."""
DRIVER_UNITS = {"temp_degC": "degC", "t_in_pose_s": "s"}


@dataclass
class PassRow:
    """One visit of a pose: span, temperature range, mean residual (g) +- sem, chi2/dof."""

    pose: str
    visit: int
    start_s: float
    end_s: float
    temp_min_degC: float | None
    temp_max_degC: float | None
    n_windows: int
    mean_resid_g: np.ndarray
    sem_g: np.ndarray
    chi2_dof: float

    def to_dict(self) -> dict:
        return {
            "pose": self.pose,
            "visit": self.visit,
            "start_s": self.start_s,
            "end_s": self.end_s,
            "temp_min_degC": self.temp_min_degC,
            "temp_max_degC": self.temp_max_degC,
            "n_windows": self.n_windows,
            "mean_residual_g": self.mean_resid_g.tolist(),
            "sem_g": self.sem_g.tolist(),
            "chi2_dof": self.chi2_dof,
        }


@dataclass
class TrendRow:
    """Slope of one pose's window residuals against a driver (g per driver unit) +- sigma."""

    pose: str
    driver: str
    slope_g_per_unit: np.ndarray
    sigma_g_per_unit: np.ndarray
    span: float
    flagged: bool

    @property
    def z(self) -> np.ndarray:
        return np.abs(self.slope_g_per_unit) / np.maximum(self.sigma_g_per_unit, 1e-300)

    def to_dict(self) -> dict:
        return {
            "pose": self.pose,
            "driver": self.driver,
            "unit": f"g/{DRIVER_UNITS[self.driver]}",
            "slope": self.slope_g_per_unit.tolist(),
            "sigma": self.sigma_g_per_unit.tolist(),
            "span": self.span,
            "flagged": self.flagged,
        }


def pass_ids(obs: ObsTable) -> np.ndarray:
    """(n,) pass number of every window: a new pass where the pose changes or its hold restarts."""
    pid = np.asarray(obs.pose_id)
    tin = np.asarray(obs.t_in_pose_s, float)
    new = np.ones(pid.size, bool)
    new[1:] = (pid[1:] != pid[:-1]) | (tin[1:] < tin[:-1])
    return np.cumsum(new) - 1


def _wmean(r: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    w = 1.0 / s**2
    return np.sum(r * w, axis=0) / np.sum(w, axis=0), 1.0 / np.sqrt(np.sum(w, axis=0))


def passes(obs: ObsTable, r_g: np.ndarray) -> list[PassRow]:
    """One row per pass, in recording order (module doc)."""
    ids = pass_ids(obs)
    sig = np.asarray(obs.sigma_g, float)
    temp = None if obs.temp_degC is None else np.asarray(obs.temp_degC, float)
    visits: dict[int, int] = {}
    rows = []
    for k in range(int(ids.max()) + 1 if ids.size else 0):  # passes, not samples
        m = ids == k
        pose = int(obs.pose_id[m][0])
        visits[pose] = visits.get(pose, 0) + 1
        mean, sem = _wmean(r_g[m], sig[m])
        tk = None if temp is None or not np.isfinite(temp[m]).all() else temp[m]
        rows.append(
            PassRow(
                pose=obs.pose_names[pose],
                visit=visits[pose],
                start_s=float(obs.t_s[m][0]),
                end_s=float(obs.t_s[m][-1]),
                temp_min_degC=None if tk is None else float(tk.min()),
                temp_max_degC=None if tk is None else float(tk.max()),
                n_windows=int(m.sum()),
                mean_resid_g=mean,
                sem_g=sem,
                chi2_dof=float(np.sum((r_g[m] / sig[m]) ** 2) / (3 * m.sum())),
            )
        )
    return rows


def disagreements(rows: list[PassRow]) -> dict[str, tuple[float, int, float]]:
    """pose -> (chi2, dof, p) of its passes against their common mean (poses with >= 2 passes)."""
    from accellog.core.numeric import chi2_sf

    out = {}
    for pose in dict.fromkeys(r.pose for r in rows):
        ps = [r for r in rows if r.pose == pose]
        if len(ps) < 2:
            continue
        m = np.array([p.mean_resid_g for p in ps])
        s = np.array([p.sem_g for p in ps])
        common, _ = _wmean(m, s)
        chi2 = float(np.sum(((m - common) / s) ** 2))
        dof = 3 * (len(ps) - 1)
        out[pose] = (chi2, dof, chi2_sf(chi2, dof))
    return out


def trends(obs: ObsTable, r_g: np.ndarray) -> list[TrendRow]:
    """Per pose and driver (temperature, time in the hold) the weighted slope of the window residuals."""
    sig = np.asarray(obs.sigma_g, float)
    drivers = {"t_in_pose_s": np.asarray(obs.t_in_pose_s, float)}
    if obs.temp_degC is not None and np.isfinite(obs.temp_degC).all():
        drivers = {"temp_degC": np.asarray(obs.temp_degC, float), **drivers}
    rows = []
    for i, pose in enumerate(obs.pose_names):
        m = np.asarray(obs.pose_id) == i
        for name, x in drivers.items():
            span = float(np.ptp(x[m])) if m.sum() else 0.0
            if m.sum() < 4 or span < MIN_SPAN[name]:
                continue
            c, sc = _slope(x[m], r_g[m], sig[m])
            rows.append(TrendRow(pose, name, c, sc, span, bool(np.any(np.abs(c) > Z_TREND * sc))))
    return rows


def _slope(x: np.ndarray, r: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted least-squares slope (3,) and its sigma per axis, Birge-inflated (module doc)."""
    slope, sigma = np.zeros(3), np.zeros(3)
    for j in range(3):  # 3 axes
        w = 1.0 / s[:, j] ** 2
        xm = np.sum(w * x) / np.sum(w)
        sxx = np.sum(w * (x - xm) ** 2)
        c = np.sum(w * (x - xm) * r[:, j]) / sxx
        a = np.sum(w * r[:, j]) / np.sum(w) - c * xm
        chi2 = np.sum(w * (r[:, j] - a - c * x) ** 2) / max(x.size - 2, 1)
        slope[j] = c
        sigma[j] = np.sqrt(1.0 / sxx) * np.sqrt(max(chi2, 1.0))
    return slope, sigma


def flag_lines(rows: list[PassRow], trend_rows: list[TrendRow], label: str) -> list[str]:
    """At most one sentence per kind: the poses whose passes disagree beyond noise (the worst one
    in detail) and the poses whose windows trend with a driver (the steepest in sigma)."""
    lines = []
    bad = {k: v for k, v in disagreements(rows).items() if v[2] < ALPHA}
    n_multi = len({r.pose for r in rows if r.visit > 1})
    if bad:
        pose, (chi2, dof, p) = max(bad.items(), key=lambda kv: kv[1][0] / kv[1][1])
        ps = [r for r in rows if r.pose == pose]
        j = int(np.argmax(np.ptp([r.mean_resid_g for r in ps], axis=0)))
        parts = " vs ".join(
            f"visit {r.visit} ({_temp(r)}) {1e3 * r.mean_resid_g[j]:+.3g} +- {1e3 * r.sem_g[j]:.2g} mg"
            for r in ps
        )
        lines.append(
            f"{label}: passes disagree beyond noise in {len(bad)} of {n_multi} revisited poses "
            f"({', '.join(bad)}); worst {pose} (chi2 {chi2:.3g} / {dof}, p {_p(p)}), "
            f"{AXES[j]}: {parts}: the pose means hide this"
        )
    for driver, u in DRIVER_UNITS.items():
        flagged = [t for t in trend_rows if t.flagged and t.driver == driver]
        if not flagged:
            continue
        t = max(flagged, key=lambda r: float(np.max(r.z)))
        j = int(np.argmax(t.z))
        lines.append(
            f"{label}: residuals trend with {driver} inside {len(flagged)} of "
            f"{len({r.pose for r in trend_rows if r.driver == driver})} poses ({', '.join(r.pose for r in flagged)}); "
            f"steepest {t.pose}: {AXES[j]} {1e3 * t.slope_g_per_unit[j]:+.3g} +- "
            f"{1e3 * t.sigma_g_per_unit[j]:.2g} mg/{u} ({t.z[j]:.1f} sigma) over {t.span:.3g} {u}"
        )
    return lines


def _p(p: float) -> str:
    return f"{p:.1e}" if p > 1e-300 else "< 1e-300"


def _temp(r: PassRow) -> str:
    if r.temp_min_degC is None:
        return f"{r.start_s:.0f}-{r.end_s:.0f} s"
    return f"{r.start_s:.0f}-{r.end_s:.0f} s, {r.temp_min_degC:.1f}-{r.temp_max_degC:.1f} degC"


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
    """One row per visit of a pose (passes)."""
    trends: list[TrendRow] = field(default_factory=list)
    """Slopes of each pose's window residuals against temperature and time in the hold."""
    flags: list[str] = field(default_factory=list)
    """Poses whose passes disagree beyond noise or whose windows trend (sentences)."""
    window_resid_g: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
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
