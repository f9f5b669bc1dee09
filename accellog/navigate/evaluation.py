"""The evaluation of a calibration on a different static session (the seed's Tables 4 and 5).

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
This module holds the result and its formulas; navigate.evaluate feeds them (running sums of
navigate.stream_sums.ResidualSums over the session's blocks). Window by window: navigate.window_evaluation.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from accellog.calibrate.calfile.calibration import Calibration
from accellog.calibrate.calfile.drift_model import DriftModel
from accellog.calibrate.model.session_drivers import session_drivers
from accellog.calibrate.noise.noise_model import sem_with_noise_floor
from accellog.core.errors import InputError
from accellog.core.jsonio import JsonResult
from accellog.core.session import Session

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
        if self.drift_applied and self.disp_drift_m is not None and self.disp_end_drift_m is not None:
            d["displacement"]["disp_after_drift_m"] = self.disp_drift_m.tolist()
            d["displacement"]["disp_end_after_drift_m"] = self.disp_end_drift_m.tolist()
            d["displacement_60s_after_drift_m"] = (
                self.disp_at(60.0, drift=True).tolist() if np.any(self.times_s == 60.0) else None
            )
        return d


def norm_refusal(mean_reading_g: np.ndarray, where: str | None) -> InputError | None:
    """The InputError when |mean reading| at rest is not 0.5-2 g (raw counts declared as g, wrong
    units, or not at rest), else None."""
    norm = float(np.linalg.norm(mean_reading_g))
    if 0.5 <= norm <= 2.0:
        return None
    return InputError(
        f"|accel| at rest is {norm:.4g} g, expected about 1 g"
        + (" (are raw counts declared as g?)" if norm > 2 else ""),
        where=where,
    )


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


def infer_up(mean_reading_g: np.ndarray, notes: list[str]) -> np.ndarray:
    """The face whose axis carries the largest |mean reading| (a noted guess, not a label)."""
    m = np.asarray(mean_reading_g, float)
    i = int(np.argmax(np.abs(m)))
    up = np.zeros(3)
    up[i] = np.sign(m[i])
    notes.append(f"orientation inferred from the mean reading: {'+' if up[i] > 0 else '-'}{AXES[i]} up")
    return up


@dataclass
class EvalContext:
    """What one evaluation of one static session needs besides the samples (units: m/s^2)."""

    cal: Calibration | None
    label: str
    session: str
    up: np.ndarray
    g_local: float
    unit: float
    """m/s^2 per unit of the evaluated output."""
    quantum_mps2: float
    notes: list[str]
    drift: DriftModel | None = None
    """The calibration's drift model when it applies to this orientation (see drift_for)."""


def eval_context(
    session_name: str,
    meta,
    cal: Calibration | None,
    up: np.ndarray,
    notes: list[str],
    *,
    label: str | None = None,
    local_gravity_mps2: float | None = None,
    raw_truth_g: float = 1.0,
    apply_drift: bool = True,
) -> EvalContext:
    """Units, label and the applicable drift model of one evaluation (cal None: the raw reading)."""
    if cal is not None:
        g_local = float(local_gravity_mps2 or cal.local_gravity_mps2)
        unit = g_local / cal.truth_g
        name = cal.model_spec.get("name", "calibrated")
    else:
        g_local = float(local_gravity_mps2 or meta.local_gravity_mps2)
        unit = g_local / raw_truth_g
        name = "no calibration"
    q = (unit / meta.accel_lsb_per_g) if meta.accel_lsb_per_g else 0.0
    ctx = EvalContext(cal, label or name, session_name, np.asarray(up, float), g_local, unit, q, notes)
    if cal is not None and cal.drift is not None and apply_drift:
        dm = cal.drift
        if dm.up_sensor is not None and not np.allclose(dm.up_sensor, ctx.up, atol=1e-6):
            notes.append(
                f"drift model not applied: fitted with up {list(dm.up_sensor)}, this session has up {ctx.up.tolist()}"
            )
        else:
            ctx.drift = dm
    return ctx


def block_residual(ctx: EvalContext, block: Session) -> np.ndarray:
    """resid = correct(reading) * unit - up * g_local (n,3) m/s^2 of consecutive samples."""
    f = ctx.cal.correct(block) if ctx.cal is not None else block.accel_g
    return f * ctx.unit - ctx.up * ctx.g_local


def driver_sums(cal: Calibration | None, block: Session) -> dict[str, float]:
    """Sums over the block of the drivers the calibration's model needs (for their session mean)."""
    if cal is None:
        return {}
    return {k: float(np.sum(v)) for k, v in session_drivers(block, cal.model.required_drivers).items()}


def finish_evaluation(
    ctx: EvalContext, st: dict, reading_mean_g: np.ndarray, drv_mean: dict[str, float], times_s
) -> Evaluation:
    """The Evaluation from ResidualSums.finish() statistics (see the module doc for the formulas)."""
    n = int(st["n"])
    mean, std = st["mean"], st["std"]
    sem = np.maximum(std * np.sqrt(st["tau"] / n), ctx.quantum_mps2 / np.sqrt(12.0 * n))
    duration = float(st["t_last"] - st["t_first"])
    cal = ctx.cal
    if cal is not None and cal.noise is not None:  # the calibration's measured white noise is the floor
        sem = sem_with_noise_floor(cal.noise, sem, duration)
        ctx.notes.append("noise floor: at least the white noise of the calibration's noise section")
    cal_sigma = np.zeros(3)
    if cal is not None:
        drv = {k: np.array([v]) for k, v in drv_mean.items()}
        cal_sigma = _cal_sigma_mps2(cal, np.asarray(reading_mean_g, float), drv, ctx.unit)
    tot = sem**2 + np.nan_to_num(cal_sigma) ** 2
    series = st.get("series", {})
    ev = Evaluation(
        label=ctx.label,
        session=ctx.session,
        up_sensor=ctx.up,
        n=n,
        duration_s=duration,
        local_gravity_mps2=ctx.g_local,
        mps2_per_unit=ctx.unit,
        mean_resid_mps2=mean,
        sem_mps2=sem,
        std_mps2=std,
        cal_sigma_mps2=cal_sigma,
        chi2_noise=float(np.sum((mean / sem) ** 2)),
        chi2_total=float(np.sum(mean**2 / tot)),
        dof=3,
        rms_mps2=st["rms"],
        times_s=np.asarray(times_s, float),
        t_used_s=st["t_used"],
        disp_m=st["disp_at"],
        t_end_s=float(st["t_last"]),
        disp_end_m=st["disp_end"],
        notes=ctx.notes,
        t_s=series.get("t"),
        resid_series_mps2=series.get("r"),
        disp_series_m=series.get("d"),
    )
    if ctx.drift is not None:
        drift_result(ev, ctx.drift, st, series)
    return ev


def drift_result(ev: Evaluation, dm: DriftModel, st: dict, series: dict) -> None:
    ev.drift_applied = True
    ev.disp_drift_series_m = series.get("dd")
    ev.disp_drift_m = st["disp_drift_at"]
    ev.disp_end_drift_m = st["disp_drift_end"]
    if ev.duration_s > 1.05 * dm.fit_duration_s:
        ev.notes.append(
            f"drift model fitted over {dm.fit_duration_s:.1f} s, applied over {ev.duration_s:.1f} s: extrapolated"
        )
    ev.notes.append("drift model: " + dm.limits)
