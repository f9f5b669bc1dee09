"""Least-squares fit of a Model to static observations, with parameter uncertainties.

Residual of row r, axis i: e_ri = meas_ri - predict(theta, f_r)_i, f_r = model.truth_g(theta, up_r, q_r, g).
Weighted fit minimises chi2 = sum (e_ri / sigma_ri)^2 (sigma_g = standard error of each window mean);
unweighted minimises sum e_ri^2 (the seed's published fits).

Covariance convention:
- weighted: cov = (J^T W J)^-1, W = diag(1/sigma^2) -- the Cramer-Rao bound for known noise; it is
  NOT rescaled by chi2/dof (if chi2/dof >> 1 the model misses an effect: a warning says so and
  `sigma_scaled` = sigma * sqrt(max(1, chi2/dof)) gives the conservative value);
- unweighted: cov = s^2 (J^T J)^-1 with s^2 = sum e^2 / dof (residual variance).
chi2/dof is always computed against the noise estimate sigma_g (when it is finite and positive).

Solver: MINPACK's Levenberg-Marquardt (scipy's, via core.numeric.least_squares, tolerances 1e-12)
with a central-difference Jacobian, each parameter scaled by its typical magnitude; a fit that
does not converge is a ModelError naming it. Before fitting, a rank check on the column-normalised
Jacobian (accellog.calibrate.model.identifiability) refuses (ModelError) models the data cannot determine,
naming the parameters and the poses or signals that are missing.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from accellog.calibrate.model.acceptance import acceptance_warnings
from accellog.calibrate.model.compose import Model
from accellog.calibrate.model.identifiability import (
    GEOMETRY_EFFECTS,
    effect_requirement,
    q_or_none,
    rank_check,
)
from accellog.calibrate.model.jacobian import norm_jacobian, numeric_columns, predict_jacobian
from accellog.calibrate.model.prior import Prior
from accellog.calibrate.model.residual_fns import Residuals, numjac, restricted, with_prior
from accellog.core.errors import InputError, ModelError
from accellog.core.numeric import chi2_sf, least_squares
from accellog.core.reprs import fit_text, param_table_html, short_repr
from accellog.core.session import ObsTable


def obs_drivers(obs: ObsTable, extra: Mapping[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
    """Driver signals of the observation rows: t_s, t_in_pose_s, temp_degC, dtemp_degC_per_s (when
    recorded and finite) plus `extra` (user signals, arrays aligned with rows)."""
    d: dict[str, np.ndarray] = {
        "t_s": np.asarray(obs.t_s, float),
        "t_in_pose_s": np.asarray(obs.t_in_pose_s, float),
    }
    for key in ("temp_degC", "dtemp_degC_per_s"):
        v = getattr(obs, key)
        if v is not None and np.all(np.isfinite(v)):
            d[key] = np.asarray(v, float)
    for k, v in (extra or {}).items():
        arr = np.asarray(v, float)
        if arr.shape[0] != obs.n:
            raise InputError(f"driver {k!r} has {arr.shape[0]} rows, observations have {obs.n}")
        d[k] = arr
    return d


@dataclass
class FitResult:
    """Outcome of a fit. residual_g = meas - predicted; S, b: linear part at reference conditions."""

    model: Model
    theta: np.ndarray
    cov: np.ndarray
    sigma: np.ndarray
    param_names: list[str]
    param_units: list[str]
    predicted_g: np.ndarray
    residual_g: np.ndarray
    truth_g: np.ndarray
    chi2: float
    dof: int
    chi2_dof: float
    p_value: float
    rms_g: float
    weighted: bool
    S: np.ndarray
    b: np.ndarray
    n_obs: int
    gravity_g: float
    method: str = "labelled"
    sigma_scaled: np.ndarray = field(default_factory=lambda: np.zeros(0))
    warnings: list[str] = field(default_factory=list)
    jacobian: np.ndarray | None = None
    """Jacobian d(w residual)/d(theta) at the solution, w = 1/sigma_g when weighted (whitened), else 1
    (rows: obs-major, axis-minor)."""
    uncertainty: str = "noise"
    """How cov/sigma were obtained: 'noise' (window noise only), 'between_hold' (plus a between-hold
    variance component) or 'jackknife' (leave one hold out); see accellog.calibrate.model.variance."""
    between_hold_g: list[float] | None = None
    """Estimated between-hold standard deviation (g) along gravity and across it ([along] for the
    gravity norm), when a hold-scatter method was used."""
    uncertainty_note: str = ""
    """Which 1-sigma cov/sigma are, in words (set by accellog.calibrate.model.variance.with_uncertainty)."""
    fixed: list[str] = field(default_factory=list)
    """Parameters held at their start values (not identifiable from the data; sigma 0)."""
    prior_sources: list[dict] | None = None
    """With a prior (calibrate.model.prior.Prior.sources): per parameter which source determined it."""
    identification: Any = None
    """What the stops identified (calibrate.model.stops.StopIdentification), field fits."""
    obs: ObsTable | None = field(default=None, repr=False, compare=False)
    """The observations fitted (held-out scores take the session's between-hold scatter from them)."""
    _recompute: Callable[[], np.ndarray] | None = field(default=None, init=False, repr=False, compare=False)
    derived: dict[Any, Any] = field(default_factory=dict, init=False, repr=False, compare=False)
    """Values later stages derive from this fit, made once (the held-out score's covariance)."""

    def release_jacobian(self) -> None:
        """Free the stored Jacobian (3 n_obs x n_params floats: ~20 MB at 24 h of windows); reading
        `jacobian` then recomputes it, bit for bit, from the fit (fits made by fit_model and
        fit_orientation_free; others keep theirs)."""
        if self._recompute is not None:
            self.__dict__["_jacobian"] = None

    def params(self) -> dict[str, float]:
        """Parameter name -> value (units: ``param_units``)."""
        return self.model.params_dict(self.theta)

    def __repr__(self) -> str:
        stats = fit_text(self.model.name, len(self.theta), self.chi2_dof, self.rms_g)
        fixed = f"{len(self.fixed)} fixed" if self.fixed else None
        warned = f"{len(self.warnings)} warnings" if self.warnings else None
        how = f"{self.method}, {self.n_obs} obs, 1-sigma from {self.uncertainty}"
        return short_repr("FitResult", [stats, how, fixed, warned])

    def _repr_html_(self) -> str:
        stats = fit_text(self.model.name, len(self.theta), self.chi2_dof, self.rms_g)
        return param_table_html(stats, self.param_names, self.param_units, self.theta, self.sigma)

    def to_dict(self) -> dict:
        """JSON-able summary: parameters with units and 1-sigma, fit statistics, warnings."""
        return {
            "model": self.model.to_spec(),
            "method": self.method,
            "weighted": self.weighted,
            "gravity_g": self.gravity_g,
            "params": [
                {"name": n, "value": float(v), "sigma": float(s), "unit": u}
                for n, v, s, u in zip(self.param_names, self.theta, self.sigma, self.param_units, strict=True)
            ],
            "cov": self.cov.tolist(),
            "S": self.S.tolist(),
            "b_g": self.b.tolist(),
            "chi2": _f(self.chi2),
            "dof": self.dof,
            "chi2_dof": _f(self.chi2_dof),
            "p_value": _f(self.p_value),
            "rms_g": self.rms_g,
            "n_obs": self.n_obs,
            "warnings": list(self.warnings),
            "uncertainty": self.uncertainty,
            "between_hold_g": self.between_hold_g,
            "uncertainty_note": self.uncertainty_note,
            **({"fixed": list(self.fixed)} if self.fixed else {}),
            **({"prior_sources": self.prior_sources} if self.prior_sources is not None else {}),
            **({"identification": self.identification.to_dict()} if self.identification is not None else {}),
        }


def _get_jacobian(self: FitResult) -> np.ndarray | None:
    j = self.__dict__.get("_jacobian")
    return self._recompute() if j is None and self._recompute is not None else j


def _set_jacobian(self: FitResult, value: np.ndarray | None) -> None:
    self.__dict__["_jacobian"] = value


FitResult.jacobian = property(_get_jacobian, _set_jacobian)  # type: ignore[assignment]


def _f(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def _sigma_ok(obs: ObsTable) -> bool:
    s = np.asarray(obs.sigma_g, float)
    return s.shape == obs.meas_g.shape and bool(np.all(np.isfinite(s) & (s > 0)))


def _checked(
    obs: ObsTable, model: Model, weighted: bool, drivers: Mapping[str, np.ndarray] | None
) -> tuple[np.ndarray, dict[str, np.ndarray], bool]:
    """(meas_g (n,3), drivers, sigma usable) after the input checks shared by both fits (InputError)."""
    if obs.n == 0:
        raise InputError("no observations to fit")
    meas = np.asarray(obs.meas_g, float)
    if not np.all(np.isfinite(meas)):
        raise InputError("observations contain NaN/inf readings")
    drv = obs_drivers(obs, drivers)
    model.check_drivers(drv, obs.n)
    sig_ok = _sigma_ok(obs)
    if weighted and not sig_ok:
        raise InputError(
            "weighted fit needs finite positive sigma_g for every observation (or weighted=False)"
        )
    return meas, drv, sig_ok


@dataclass
class _Problem:
    model: Model
    obs: ObsTable
    drivers: dict[str, np.ndarray]
    w: np.ndarray  # (n,3) 1/sigma or ones
    gravity_g: float
    q: np.ndarray | None

    def predicted(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        f = self.model.truth_g(theta, self.obs.up_sensor, self.q, self.gravity_g)
        return self.model.predict(theta, f, self.drivers), f

    def resid(self, theta: np.ndarray) -> np.ndarray:
        return ((self.obs.meas_g - self.predicted(theta)[0]) * self.w).ravel()

    def analytic(self, theta: np.ndarray) -> tuple[np.ndarray, list[int]]:
        """d resid / d theta: the library columns analytic, the rest (fixture_tilt, user) to differences."""
        f = self.model.truth_g(theta, self.obs.up_sensor, self.q, self.gravity_g)
        J = predict_jacobian(self.model, theta, f, self.drivers)
        J *= -self.w[:, :, None]  # in place: one Jacobian in memory
        return J.reshape(-1, theta.size), numeric_columns(self.model)


def _chi2_sf(chi2: float, dof: int) -> float:
    """P(X > chi2) for X ~ chi2(dof) (NaN for dof <= 0): scipy.special.chdtrc (core.numeric.chi2_sf)."""
    return chi2_sf(float(chi2), dof)


def _steps(model: Model, theta: np.ndarray) -> np.ndarray:
    return np.maximum(1e-4 * model.param_typical, 1e-7 * np.abs(theta))


def _solve(fun, theta0: np.ndarray, model: Model, what: str, free: np.ndarray | None = None) -> np.ndarray:
    """min sum fun(theta)^2 from theta0 over the free parameters (all by default; the others stay at
    theta0): scipy's Levenberg-Marquardt (core.numeric.least_squares) with the central-difference
    Jacobian, parameters scaled by their typical size; ModelError naming `what` if it does not converge."""
    free = np.ones(theta0.size, bool) if free is None else free
    sub = restricted(fun, theta0, free) if not free.all() else fun
    full = getattr(sub, "full", lambda x: x)
    jac = lambda x: numjac(sub, x, _steps(model, full(x))[free])  # noqa: E731
    return full(least_squares(sub, theta0[free], what=what, jac=jac, x_scale=model.param_typical[free]).x)


def _warmup_init(problem: _Problem, theta0: np.ndarray, wfun) -> np.ndarray:
    """Grid over tau_warmup_s (model linear given tau): best start for the nonlinear fit."""
    k = problem.model.index["tau_warmup_s"]
    span = max(float(np.ptp(problem.drivers["t_s"])), 1.0)
    best, best_cost = theta0, np.inf
    free = [i for i in range(theta0.size) if i != k]
    for tau in np.geomspace(max(span / 300, 1.0), span, 9):
        th = theta0.copy()
        th[k] = tau

        def f_sub(x, th=th):
            t2 = th.copy()
            t2[free] = x
            return wfun(t2)

        J = numjac(f_sub, th[free], _steps(problem.model, th)[free])
        x, *_ = np.linalg.lstsq(J, -f_sub(th[free]), rcond=None)
        th[free] += x
        c = float(np.sum(wfun(th) ** 2))
        if c < best_cost:
            best, best_cost = th, c
    return best


def fit_model(
    obs: ObsTable,
    model: Model,
    *,
    weighted: bool = True,
    gravity_g: float = 1.0,
    drivers: Mapping[str, np.ndarray] | None = None,
    theta0: np.ndarray | None = None,
    check_rank: bool = True,
) -> FitResult:
    """Least-squares fit of `model` to labelled static observations (truth = gravity_g * up_sensor,
    tilted when the model has fixture_tilt). `drivers`: extra driver signals aligned with rows."""
    meas, drv, sig_ok = _checked(obs, model, weighted, drivers)
    w = 1.0 / np.asarray(obs.sigma_g, float) if weighted else np.ones_like(meas)
    prob = _Problem(model, obs, drv, w, float(gravity_g), q_or_none(obs))
    th0 = model.initial_theta() if theta0 is None else np.asarray(theta0, float).copy()
    if check_rank:
        blind = {e.name for e in model.effects if not e.static}  # clock: nothing a pose mean shows
        for name in sorted(GEOMETRY_EFFECTS & set(model.term_names)) + sorted(blind):
            why = effect_requirement(name, obs, drv, model)
            if why:
                raise ModelError(f"model {model.name} cannot be determined from this data: {why}")
        # Probe the rank at a generic point (zero-initial parameters at half their typical size):
        # at theta0 a nonlinear parameter (tau of a zero warm-up amplitude) has no effect at all.
        probe = model.initial_theta()
        probe = np.where(probe == 0.0, 0.5 * model.param_typical, probe)
        rank_check(numjac(prob.resid, probe, _steps(model, probe)), model, obs, drv, overwrite=True)
    if "tau_warmup_s" in model.index and theta0 is None:
        th0 = _warmup_init(prob, th0, prob.resid)
    theta = _solve(prob.resid, th0, model, f"fit of {model.name}")
    return _result(prob, theta, weighted, sig_ok, method="labelled")


def _result(prob: _Problem, theta: np.ndarray, weighted: bool, sig_ok: bool, method: str) -> FitResult:
    model, obs = prob.model, prob.obs
    pred, f = prob.predicted(theta)
    res = np.asarray(obs.meas_g, float) - pred
    J = numjac(prob.resid, theta, _steps(model, theta))
    n_eq = res.size
    k = model.n_params
    dof = n_eq - k
    JtJ = J.T @ J
    try:
        cov = np.linalg.inv(JtJ)
    except np.linalg.LinAlgError:
        cov = np.linalg.pinv(JtJ)
    rss_w = float(np.sum((res * prob.w) ** 2))
    if sig_ok:
        chi2 = float(np.sum((res / np.asarray(obs.sigma_g, float)) ** 2))
        chi2_dof = chi2 / dof if dof > 0 else np.nan
        p = _chi2_sf(chi2, dof)
    else:
        chi2, chi2_dof, p = np.nan, np.nan, np.nan
    if not weighted:
        cov = cov * (rss_w / dof if dof > 0 else np.nan)
    sigma = np.sqrt(np.clip(np.diag(cov), 0, None))
    scale = max(1.0, chi2_dof) if weighted and np.isfinite(chi2_dof) else 1.0
    S, b = model.S_b(theta)
    warns = acceptance_warnings(model, S, b, chi2_dof, p, sigma, weighted, dof, theta=theta, cov=cov)
    out = FitResult(
        model=model,
        theta=theta,
        cov=cov,
        sigma=sigma,
        param_names=list(model.param_names),
        param_units=list(model.param_units),
        predicted_g=pred,
        residual_g=res,
        truth_g=f,
        chi2=chi2,
        dof=dof,
        chi2_dof=chi2_dof,
        p_value=p,
        rms_g=float(np.sqrt(np.mean(res**2))),
        weighted=weighted,
        S=S,
        b=b,
        n_obs=obs.n,
        gravity_g=prob.gravity_g,
        method=method,
        sigma_scaled=sigma * np.sqrt(scale),
        warnings=warns,
        jacobian=J,
    )
    out._recompute = _jacobian_of(prob, theta, weighted)
    out.obs = obs
    return out


def _jacobian_of(prob: _Problem, theta: np.ndarray, weighted: bool) -> Callable[[], np.ndarray]:
    """_result's Jacobian, made again from the fit's inputs (the weights too: no array is held)."""
    model, obs, drv, g, q, theta = prob.model, prob.obs, prob.drivers, prob.gravity_g, prob.q, theta.copy()

    def jac() -> np.ndarray:
        w = 1.0 / np.asarray(obs.sigma_g, float) if weighted else np.ones_like(np.asarray(obs.meas_g, float))
        return numjac(_Problem(model, obs, drv, w, g, q).resid, theta, _steps(model, theta))

    return jac


def fit_orientation_free(
    obs: ObsTable,
    model: Model,
    *,
    weighted: bool = True,
    gravity_g: float = 1.0,
    drivers: Mapping[str, np.ndarray] | None = None,
    prior: Prior | None = None,
    fixed: Sequence[str] = (),
) -> FitResult:
    """Fit without pose labels (imu_tk / ArduPilot): minimise sum ((|f_r| - g) / sigma_r)^2 with
    f_r = model.correct(theta, meas_r); sigma_r = |(f_r/|f_r|) . sigma_r| (projected noise).

    The rotation of the sensor frame is unobservable, so full cross_axis (6) cannot be fitted: use
    misalignment_tri (3). Needs >= 9 well-spread orientations for bias+scale+misalignment_tri.
    prior (calibrate.model.prior, weighted fits only): its whitened rows W (theta - theta_p) join the
    residuals and the fit starts at theta_p, so what the norm cannot see (cross_axis, fixture_tilt,
    b_z against S_zz on level stops) stays at the prior's values; FitResult.prior_sources says per
    parameter which source determined it. fixed: parameter names held at the start values (the
    terms calibrate.model.stops.identify_stops finds the stops cannot see), sigma 0.
    """
    if prior is None and model.has("fixture_tilt"):
        raise ModelError("fixture_tilt needs pose labels: the orientation-free fit cannot use it")
    if prior is None and model.has("cross_axis"):
        raise ModelError(
            "an orientation-free fit cannot determine all 6 cross_axis terms (3 of them are a rotation "
            "of the frame): use misalignment_tri instead, e.g. 'bias+scale+misalignment_tri'"
        )
    if prior is not None and (list(prior.names) != model.param_names or not weighted):
        raise ModelError(f"{prior.what}: a prior needs a weighted fit of its own parameters")
    unknown = sorted(set(fixed) - set(model.param_names))
    if unknown:
        raise ModelError(f"cannot hold {', '.join(unknown)} fixed: not parameters of {model.name}")
    free = np.array([p not in set(fixed) for p in model.param_names])
    meas, drv, sig_ok = _checked(obs, model, weighted, drivers)
    if sig_ok:
        dirs = meas / np.linalg.norm(meas, axis=1, keepdims=True)
        sig_n = np.sqrt(np.sum((dirs * obs.sigma_g) ** 2, axis=1))
    else:
        sig_n = np.ones(obs.n)
    wn = 1.0 / sig_n if weighted else np.ones(obs.n)

    def norm(theta):
        f = model.correct(theta, meas, drv)
        return (np.linalg.norm(f, axis=1) - gravity_g) * wn

    def analytic(theta):
        J = norm_jacobian(model, theta, meas, drv)
        return None if J is None else (J * wn[:, None], numeric_columns(model))

    fun = with_prior(Residuals(norm, analytic), prior)
    th0 = model.initial_theta() if prior is None else prior.theta.copy()
    if prior is None:
        _norm_rank_check(restricted(fun, th0, free), th0, model, obs, free)
    theta = _solve(fun, th0, model, f"orientation-free fit of {model.name}", free)
    w = 1.0 / np.asarray(obs.sigma_g, float) if weighted else np.ones_like(meas)
    prob = _Problem(model, _implied_truth(obs, model, theta, drv, gravity_g), drv, w, float(gravity_g), None)
    out = _result(prob, theta, weighted, sig_ok, method="orientation_free")
    _norm_statistics(out, (norm, fun), theta, weighted, sig_ok, (wn, sig_n), free)
    out.fixed = [p for p in model.param_names if p in set(fixed)]
    if prior is not None:
        out.prior_sources = prior.sources(theta, out.cov)
    return out


def _norm_rank_check(sub, th0: np.ndarray, model: Model, obs: ObsTable, free: np.ndarray) -> None:
    """Refuse (ModelError) a norm fit of the free parameters (sub: _restricted) with fewer rows
    than parameters or a rank-deficient Jacobian."""
    names = [p for p, f in zip(model.param_names, free, strict=True) if f]
    J0 = numjac(sub, th0[free], _steps(model, th0)[free])
    if J0.shape[0] < J0.shape[1]:
        raise ModelError(
            f"orientation-free fit of {model.name} needs >= {len(names)} distinct static "
            f"orientations, have {obs.n}"
        )
    norms = np.linalg.norm(J0, axis=0)
    _, s, vt = np.linalg.svd(J0 / np.where(norms > 0, norms, 1.0), full_matrices=False)
    if np.any(norms == 0) or s[-1] < 1e-7 * s[0]:
        bad = [names[k] for k in np.flatnonzero((norms == 0) | (np.abs(vt[-1]) > 0.2))]
        from accellog.calibrate.model.identifiability import NORM_ONLY_LABELLED, norm_blind_params

        blind = norm_blind_params(model)  # more orientations would not help these
        raise ModelError(
            f"orientation-free fit cannot determine {', '.join(bad)}: "
            + (
                f"{', '.join(blind)} {NORM_ONLY_LABELLED}"
                if blind
                else "record more, well-spread orientations (>= 9, including tilted ones)"
            )
        )


def _implied_truth(obs: ObsTable, model: Model, theta: np.ndarray, drv, gravity_g: float) -> ObsTable:
    """obs with the truth implied by the fit: up = the corrected direction (f scaled to gravity)."""
    f = model.correct(theta, np.asarray(obs.meas_g, float), drv)
    up = f / np.linalg.norm(f, axis=1, keepdims=True)
    return dataclasses.replace(obs, up_sensor=up, q_sensor_to_world=None)


def _norm_statistics(out: FitResult, funs, theta, weighted: bool, sig_ok: bool, weights, free) -> None:
    """Covariance, chi2 and acceptance checks of `out` from the residuals actually fitted (funs: the
    norm rows and the whole objective, with a prior's rows; weights: (wn, sig_n), weight and
    projected sigma per row; free: the parameters fitted, a fixed one has sigma 0), replacing the
    labelled-style ones of _result."""
    (norm, fun), (wn, sig_n) = funs, weights
    model = out.model
    J = numjac(fun, theta, _steps(model, theta))[:, free]
    cov = np.zeros((theta.size, theta.size))
    cov[np.ix_(free, free)] = np.linalg.pinv(J.T @ J)
    r, rr = norm(theta), fun(theta)
    dof = rr.size - int(free.sum())
    if not weighted:
        cov = cov * (float(r @ r) / dof if dof > 0 else np.nan)
    out.cov = cov
    out.sigma = np.sqrt(np.clip(np.diag(cov), 0, None))
    out.dof = dof
    if sig_ok:
        out.chi2 = float(np.sum((r / wn / sig_n) ** 2) + np.sum(rr[r.size :] ** 2))
        out.chi2_dof = out.chi2 / dof if dof > 0 else np.nan
        out.p_value = _chi2_sf(out.chi2, dof)
    scale = max(1.0, out.chi2_dof) if weighted and np.isfinite(out.chi2_dof) else 1.0
    out.sigma_scaled = out.sigma * np.sqrt(scale)  # as _result: the unweighted cov already carries s^2
    # the acceptance checks of _result saw the labelled-style statistics: redo them on the fitted ones
    out.warnings = acceptance_warnings(
        model, out.S, out.b, out.chi2_dof, out.p_value, out.sigma, weighted, dof, theta=out.theta, cov=out.cov
    )
