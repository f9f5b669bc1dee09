"""Evaluate a calibration on a different static session (the seed's Tables 4 and 5).

For a session at rest in one orientation (up vector u, sensor frame):

    a (m/s^2)  = correct(theta, reading) * mps2_per_unit          (calibrated specific force)
    r (m/s^2)  = a - u * g_local                                   (residual; seed: minus 9.797 on z)
    mean_r +- sem (autocorrelation-aware), std, residual RMS of window means,
    chi2_noise = sum_axes (mean_r / sem)^2   (dof 3): is the residual explained by noise alone?
    chi2_total = sum_axes mean_r^2 / (sem^2 + sigma_cal^2), sigma_cal propagated from the
                 calibration covariance through correct() (numerical Jacobian),
    d(t) = double trapezoid integral of r over the real timestamps, reported at 10/30/60 s,
    and after the drift model when the calibration carries one (d - 1/2 q2 t^2 - q1 t - q0).

`cal=None` evaluates the raw reading (the seed's "No calibration" row: a = reading * g_local).
`evaluate_poses` evaluates a multi-pose session window by window; its displacement at 60 s is per
hold, extrapolated from the hold's mean residual as if it persisted from rest:
d_k(60 s) = 1/2 mean_r_k (m/s^2) (60 s)^2 (holds are shorter than 60 s; for a constant residual this
is what the double integral gives).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from accellog.calibrate.calibration import Calibration, session_drivers
from accellog.calibrate.noise import sem_autocorr
from accellog.calibrate.noise_model import sem_with_noise_floor
from accellog.calibrate.segment import check_static, observations
from accellog.core.errors import InputError
from accellog.core.jsonio import JsonResult
from accellog.core.session import PoseLabel, Session
from accellog.navigate.integrate import DEFAULT_TIMES_S, displacement, values_at

AXES = ("x", "y", "z")


@dataclass
class Evaluation(JsonResult):
    """Result of evaluating one calibration (or none) on one static session. m/s^2, m, s."""

    label: str
    session: str
    up_sensor: np.ndarray
    n: int
    duration_s: float
    local_gravity_mps2: float
    mps2_per_unit: float
    mean_resid_mps2: np.ndarray
    sem_mps2: np.ndarray
    std_mps2: np.ndarray
    cal_sigma_mps2: np.ndarray
    chi2_noise: float
    chi2_total: float
    dof: int
    rms_mps2: float
    times_s: np.ndarray
    t_used_s: np.ndarray
    disp_m: np.ndarray  # (m,3) at times_s
    t_end_s: float
    disp_end_m: np.ndarray
    drift_applied: bool = False
    disp_drift_m: np.ndarray | None = None  # (m,3) after the drift model
    disp_end_drift_m: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)
    # full series (for plots / .rrd; not in to_dict)
    t_s: np.ndarray | None = None
    resid_series_mps2: np.ndarray | None = None
    disp_series_m: np.ndarray | None = None
    disp_drift_series_m: np.ndarray | None = None

    @property
    def rms_g(self) -> float:
        """Residual RMS in calibrated units (g): rms_mps2 / mps2_per_unit."""
        return self.rms_mps2 / self.mps2_per_unit

    @property
    def chi2_noise_dof(self) -> float:
        return self.chi2_noise / self.dof

    def disp_at(self, t: float, drift: bool = False) -> np.ndarray:
        """Displacement (3,) m at one of the reported times (after the drift model if drift)."""
        i = int(np.argmin(np.abs(self.times_s - t)))
        src = self.disp_drift_m if drift and self.disp_drift_m is not None else self.disp_m
        return src[i]

    def to_dict(self) -> dict:
        d = {
            "label": self.label,
            "session": self.session,
            "up_sensor": self.up_sensor.tolist(),
            "n_samples": self.n,
            "duration_s": self.duration_s,
            "local_gravity_mps2": self.local_gravity_mps2,
            "mps2_per_unit": self.mps2_per_unit,
            "mean_residual_mps2": dict(zip(AXES, self.mean_resid_mps2.tolist(), strict=True)),
            "sem_mps2": dict(zip(AXES, self.sem_mps2.tolist(), strict=True)),
            "std_mps2": dict(zip(AXES, self.std_mps2.tolist(), strict=True)),
            "calibration_sigma_mps2": dict(zip(AXES, self.cal_sigma_mps2.tolist(), strict=True)),
            "chi2_noise": self.chi2_noise,
            "chi2_total": self.chi2_total,
            "dof": self.dof,
            "chi2_noise_dof": self.chi2_noise_dof,
            "rms_mps2": self.rms_mps2,
            "rms_g": self.rms_g,
            "displacement": {
                "times_s": self.times_s.tolist(),
                "t_used_s": self.t_used_s.tolist(),
                "disp_m": self.disp_m.tolist(),
                "t_end_s": self.t_end_s,
                "disp_end_m": self.disp_end_m.tolist(),
            },
            "displacement_60s_m": self.disp_at(60.0).tolist() if np.any(self.times_s == 60.0) else None,
            "drift_applied": self.drift_applied,
            "notes": list(self.notes),
        }
        if self.drift_applied and self.disp_drift_m is not None:
            d["displacement"]["disp_after_drift_m"] = self.disp_drift_m.tolist()
            d["displacement"]["disp_end_after_drift_m"] = self.disp_end_drift_m.tolist()
            d["displacement_60s_after_drift_m"] = (
                self.disp_at(60.0, drift=True).tolist() if np.any(self.times_s == 60.0) else None
            )
        return d


def _infer_up(session: Session, notes: list[str]) -> np.ndarray:
    if len(session.poses) == 1:
        return np.asarray(session.poses[0].up_sensor, float)
    if len(session.poses) > 1:
        raise InputError(
            f"evaluate needs a static session in one orientation; this one has {len(session.poses)} pose "
            "labels (use evaluate_poses / the pipeline's evaluate_poses stage)",
            where=session.path,
        )
    m = np.nanmean(session.accel_g, axis=0)
    i = int(np.argmax(np.abs(m)))
    up = np.zeros(3)
    up[i] = np.sign(m[i])
    notes.append(f"orientation inferred from the mean reading: {'+' if up[i] > 0 else '-'}{AXES[i]} up")
    return up


def _slice(session: Session, until_s: float | None, max_samples: int | None) -> slice:
    n = session.n
    if until_s is not None:
        n = min(n, int(np.searchsorted(session.t_s, until_s, side="right")))
    if max_samples is not None:
        n = min(n, int(max_samples))
    return slice(0, n)


def calibrated_residual(
    session: Session,
    cal: Calibration | None,
    *,
    up_sensor: Sequence[float] | None = None,
    local_gravity_mps2: float | None = None,
    raw_truth_g: float = 1.0,
    until_s: float | None = None,
    max_samples: int | None = None,
    check_moving: bool = True,
    notes: list[str] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float, np.ndarray]:
    """(t_s, resid_mps2 (n,3), up (3,), g_local, mps2_per_unit, reading_g (n,3)) of a static session.

    resid = correct(reading) * mps2_per_unit - up * g_local (m/s^2). Without a calibration the
    reading itself is used with mps2_per_unit = g_local / raw_truth_g (seed: a = reading * 9.797).
    """
    notes = notes if notes is not None else []
    where = session.path or session.meta.source
    sl = _slice(session, until_s, max_samples)
    if sl.stop < 10:
        raise InputError(f"static session has {sl.stop} samples (need >= 10)", where=where)
    t = session.t_s[sl]
    reading = session.accel_g[sl]
    if not np.isfinite(reading).all():
        i = int(np.argmax(~np.isfinite(reading).all(axis=1)))
        raise InputError(f"accel is NaN/inf at t = {t[i]:.3f} s", where=where)
    up = np.asarray(up_sensor, float) if up_sensor is not None else _infer_up(session, notes)
    if cal is not None:
        g_local = float(local_gravity_mps2 or cal.local_gravity_mps2)
        unit = g_local / cal.truth_g
    else:
        g_local = float(local_gravity_mps2 or session.meta.local_gravity_mps2)
        unit = g_local / raw_truth_g
    norm = float(np.linalg.norm(reading.mean(axis=0)))
    if not 0.5 <= norm <= 2.0:
        raise InputError(
            f"|accel| at rest is {norm:.4g} g, expected about 1 g"
            + (" (are raw counts declared as g?)" if norm > 2 else ""),
            where=where,
        )
    if check_moving:
        sub = Session(
            meta=session.meta, t_s=t, sample_index=session.sample_index[sl], accel_g=reading, path=where
        )
        label = PoseLabel("static test", float(t[0]), float(t[-1]) + 1e-9, tuple(up))
        check_static(sub, [(label, slice(0, t.size))])
    if cal is not None:
        sub = Session(
            meta=session.meta,
            t_s=t,
            sample_index=session.sample_index[sl],
            accel_g=reading,
            temp_degC=None if session.temp_degC is None else session.temp_degC[sl],
            poses=session.poses,
            path=session.path,
        )
        f = cal.correct(sub)
    else:
        f = reading
    return t, f * unit - up * g_local, up, g_local, unit, reading


def _cal_sigma_mps2(cal: Calibration, reading_mean: np.ndarray, drivers: dict, unit: float) -> np.ndarray:
    """1-sigma (3,) m/s^2 of correct(theta, mean reading) from the calibration covariance."""
    if not np.isfinite(cal.cov).all():
        return np.full(3, np.nan)
    model = cal.model
    th = cal.theta
    step = 1e-6 * np.maximum(np.abs(th), np.maximum(model.param_typical, 1e-3))
    J = np.empty((3, th.size))
    x = reading_mean[None, :]
    for k in range(th.size):  # one column per parameter (<= a few dozen), not per sample
        tp, tm = th.copy(), th.copy()
        tp[k] += step[k]
        tm[k] -= step[k]
        J[:, k] = (model.correct(tp, x, drivers)[0] - model.correct(tm, x, drivers)[0]) / (2 * step[k])
    return np.sqrt(np.clip(np.diag(J @ cal.cov @ J.T), 0, None)) * unit


def evaluate(
    session: Session,
    cal: Calibration | None,
    *,
    label: str | None = None,
    up_sensor: Sequence[float] | None = None,
    local_gravity_mps2: float | None = None,
    raw_truth_g: float = 1.0,
    times_s: Sequence[float] = DEFAULT_TIMES_S,
    until_s: float | None = None,
    max_samples: int | None = None,
    window_s: float = 2.0,
    apply_drift: bool = True,
    check_moving: bool = True,
) -> Evaluation:
    """Evaluate `cal` (None: raw reading) on a static session; see the module docstring.

    until_s / max_samples cut the session first (the seed used the first 10,800 samples of its
    300 s final test). A drift model is applied only when its orientation matches up_sensor.
    """
    notes: list[str] = []
    t, r, up, g_local, unit, reading = calibrated_residual(
        session,
        cal,
        up_sensor=up_sensor,
        local_gravity_mps2=local_gravity_mps2,
        raw_truth_g=raw_truth_g,
        until_s=until_s,
        max_samples=max_samples,
        check_moving=check_moving,
        notes=notes,
    )
    mean = r.mean(axis=0)
    std = r.std(axis=0, ddof=1)
    sem, _ = sem_autocorr(
        r, quantum=(unit / session.meta.accel_lsb_per_g) if session.meta.accel_lsb_per_g else 0.0
    )
    if cal is not None and cal.noise is not None:  # the calibration's measured white noise is the floor
        sem = sem_with_noise_floor(cal.noise, sem, float(t[-1] - t[0]))
        notes.append("noise floor: at least the white noise of the calibration's noise section")
    if cal is not None:
        drv_all = session_drivers(
            Session(
                meta=session.meta,
                t_s=t,
                sample_index=np.arange(t.size),
                accel_g=reading,
                temp_degC=None if session.temp_degC is None else session.temp_degC[: t.size],
                poses=session.poses,
            ),
            cal.model.required_drivers,
        )
        drv_mean = {k: np.array([float(np.mean(v))]) for k, v in drv_all.items()}
        cal_sigma = _cal_sigma_mps2(cal, reading.mean(axis=0), drv_mean, unit)
    else:
        cal_sigma = np.zeros(3)
    chi2_noise = float(np.sum((mean / sem) ** 2))
    tot = sem**2 + np.nan_to_num(cal_sigma) ** 2
    chi2_total = float(np.sum(mean**2 / tot))
    # window-mean RMS
    edges = np.arange(t[0], t[-1], window_s)
    starts = np.unique(np.searchsorted(t, edges))
    sums = np.add.reduceat(r, starts, axis=0)
    cnt = np.diff(np.append(starts, t.size))[:, None]
    rms = float(np.sqrt(np.mean((sums / cnt) ** 2)))
    _, disp = displacement(t, r, remove_gravity_mps2=None, where=session.path)
    tq = np.asarray(times_s, float)
    used, d_at = values_at(t, disp, tq)
    ev = Evaluation(
        label=label or (cal.model_spec.get("name", "calibrated") if cal is not None else "no calibration"),
        session=session.path or session.meta.source,
        up_sensor=up,
        n=int(t.size),
        duration_s=float(t[-1] - t[0]),
        local_gravity_mps2=g_local,
        mps2_per_unit=unit,
        mean_resid_mps2=mean,
        sem_mps2=sem,
        std_mps2=std,
        cal_sigma_mps2=cal_sigma,
        chi2_noise=chi2_noise,
        chi2_total=chi2_total,
        dof=3,
        rms_mps2=rms,
        times_s=tq,
        t_used_s=used,
        disp_m=d_at,
        t_end_s=float(t[-1]),
        disp_end_m=disp[-1].copy(),
        notes=notes,
        t_s=t,
        resid_series_mps2=r,
        disp_series_m=disp,
    )
    if cal is not None and cal.drift is not None and apply_drift:
        dm = cal.drift
        if dm.up_sensor is not None and not np.allclose(dm.up_sensor, up, atol=1e-6):
            notes.append(
                f"drift model not applied: fitted with up {list(dm.up_sensor)}, this session has up {up.tolist()}"
            )
        else:
            dd = dm.apply(t, disp)
            ev.drift_applied = True
            ev.disp_drift_series_m = dd
            ev.disp_drift_m = values_at(t, dd, tq)[1]
            ev.disp_end_drift_m = dd[-1].copy()
            if ev.duration_s > 1.05 * dm.fit_duration_s:
                notes.append(
                    f"drift model fitted over {dm.fit_duration_s:.1f} s, applied over {ev.duration_s:.1f} s: extrapolated"
                )
            notes.append("drift model: " + dm.limits)
    return ev


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
    from accellog.calibrate.fit import obs_drivers

    obs = observations(session, window_s=window_s, trim_s=trim_s)
    if cal is None:
        r = np.asarray(obs.meas_g, float) - np.asarray(obs.up_sensor, float)
        unit = float(local_gravity_mps2 or session.meta.local_gravity_mps2)
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
    return PoseEvaluation(
        label=cal.model_spec.get("name", "calibrated") if cal is not None else "no calibration",
        session=session.path or session.meta.source,
        pose_names=list(obs.pose_names),
        mean_resid_g=mean,
        sem_g=sem,
        rms_g=float(np.sqrt(np.mean(r**2))),
        chi2=float(np.sum((r / obs.sigma_g) ** 2)),
        dof=int(r.size),
        mps2_per_unit=float(unit),
        mean_resid_all_g=r.mean(axis=0),
        at_s=float(at_s),
    )
