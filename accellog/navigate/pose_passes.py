"""Per-pass and per-window residuals of a multi-pose evaluation: what one mean per pose hides.

A pass is one visit of a pose (consecutive windows of the same pose; a pose visited while heating and
again while cooling has two). For the window residuals r_w (g, per axis) with standard errors s_w:

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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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
    from scipy import stats

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
        out[pose] = (chi2, dof, float(stats.chi2.sf(chi2, dof)))
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
