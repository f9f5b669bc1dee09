"""Does a fitted model transfer to data it was not fitted on?  Evidence that exposes a proxy.

Two residuals, each function taking norm=False (labelled: per axis) or norm=True (hand-held, field:
the gravity norm, which needs no orientation; one equation per window r):

    labelled: z_r = (a'_r - predict(theta; u_r g, drivers_r)) / sigma_r        (3 per window)
    norm:     z_r = e_r / sigma_n,r,  e_r = |correct(theta; a'_r, drivers_r)| - g,
              sigma_n,r = |(a'_r / |a'_r|) . sigma_r|   (noise projected on the reading)

A candidate effect can reach chi2/dof ~ 1 on the calibration session by standing in for another
one (a warm-up in time mimics a bias that follows temperature when temperature follows time). Three
kinds of out-of-sample evidence, strongest first:

- held-out sessions:  the model fitted on the calibration session predicts each held-out session;
                      score = mean (r / sigma_g)^2 over its equations (chi2 per equation);
- blocked validation: within one session, the windows are cut into K contiguous blocks of a
                      driver (temperature range, time); each block is predicted by the fit to the
                      other blocks (whitened hat matrix H = J (J^T J)^+ J^T, block rows B:
                      r_cv,B = (I - H_BB)^-1 r_B, exact for linear models, one Gauss-Newton step
                      for nonlinear ones), so a model must extrapolate across the driver's range;
- collinearity:       two effects explain the same residual when their (whitened) Jacobian columns,
                      after removing what the base model absorbs, span nearly the same space:
                      rho = largest canonical correlation = sigma_max(Q_a^T Q_b).

A score is judged against its own noise: for a correct model chi2 per equation has standard error
~ sqrt(2 / m) over m equations.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from accellog.calibrate.model.compose import Model
from accellog.calibrate.model.effects import all_effects
from accellog.calibrate.model.fit import FitResult, obs_drivers
from accellog.core.session import ObsTable

N_BLOCKS = 5
"""Contiguous blocks of each driver for blocked validation."""
COLLINEAR_RHO = 0.95
"""Canonical correlation above which two candidates are called near-collinear on this data."""


@dataclass
class Score:
    """Out-of-sample chi2 per equation of one model; kind 'heldout' or 'blocks:<driver>'."""

    kind: str
    chi2_per_eq: float
    n_eq: int
    per_part: list[float]

    @property
    def se(self) -> float:
        """Standard error of chi2_per_eq for a model at the noise floor: sqrt(2 / m) * max(1, score)."""
        return float(np.sqrt(2.0 / max(self.n_eq, 1)) * max(1.0, self.chi2_per_eq))

    def to_dict(self) -> dict:
        return {
            "kind": self.kind,
            "chi2_per_eq": _f(self.chi2_per_eq),
            "n_eq": self.n_eq,
            "per_part": [_f(x) for x in self.per_part],
        }


def _f(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def predict_residual(res: FitResult, obs: ObsTable, theta: np.ndarray | None = None) -> np.ndarray:
    """Residual (n,3) g of a fitted model (at theta, default res.theta) on other observations (same
    pose labelling)."""
    m = res.model
    th = res.theta if theta is None else theta
    drv = obs_drivers(obs)
    q = None if obs.q_sensor_to_world is None else np.asarray(obs.q_sensor_to_world, float)
    f = m.truth_g(th, obs.up_sensor, q, res.gravity_g)
    return np.asarray(obs.meas_g, float) - m.predict(th, f, drv)


def norm_residual(res: FitResult, obs: ObsTable) -> tuple[np.ndarray, np.ndarray]:
    """(e_r, sigma_n,r) in g: the gravity-norm residual of a fitted model on the windows of `obs`
    and the window noise projected on the reading (module doc)."""
    f = res.model.correct(res.theta, np.asarray(obs.meas_g, float), obs_drivers(obs))
    return np.linalg.norm(f, axis=1) - res.gravity_g, _projected_sigma(obs)


def _projected_sigma(obs: ObsTable) -> np.ndarray:
    meas = np.asarray(obs.meas_g, float)
    dirs = meas / np.linalg.norm(meas, axis=1, keepdims=True)
    return np.sqrt(np.sum((dirs * np.asarray(obs.sigma_g, float)) ** 2, axis=1))


def _heldout_z(res: FitResult, obs: ObsTable, norm: bool) -> np.ndarray:
    """Whitened residual z of res predicting another session (module doc)."""
    if norm:
        e, s = norm_residual(res, obs)
        return e / s
    return predict_residual(res, obs) / np.asarray(obs.sigma_g, float)


def heldout_score(res: FitResult, heldout: Sequence[ObsTable], *, norm: bool = False) -> Score:
    """chi2 per equation of `res` predicting every held-out session (pooled) and per session
    (per_part); norm: the gravity-norm residual."""
    chi2, m, parts = 0.0, 0, []
    for h in heldout:
        z = _heldout_z(res, h, norm)
        c = float(np.sum(z**2))
        chi2 += c
        m += z.size
        parts.append(c / max(z.size, 1))
    return Score("heldout", chi2 / max(m, 1), m, parts)


# ---------------------------------------------------------------------------------------------
# predictive held-out score: the calibration's own uncertainty counted


def predictive_chi2(
    res: FitResult, heldout: ObsTable, *, norm: bool | None = None, scatter=None
) -> tuple[float, float, int]:
    """(predictive chi2, noise-only chi2, m equations) of `res` predicting another session.

    Residual r (per axis, or the gravity norm |correct(theta; a)| - g when norm; default: norm for
    orientation-free fits), covariance

        C = D + P Sigma P^T + sum_h U_h T_h U_h^T

    D = window noise (diagonal), P = dr/dtheta on the held-out windows, Sigma = the calibration's
    parameter covariance with its between-hold component (variance.component_cov on res.obs), T_h =
    the between-hold covariance the calibration session showed, placed on each held-out hold (U_h
    sums a hold's windows). chi2 = r^T C^-1 r by Woodbury (per hold, then over the k parameters):
    O(m k^2). A correct model scores chi2 / m ~ 1 on a second session of the same sensor. Without
    res.obs (a loaded calibration) Sigma = res.cov and T_h = 0.

    The scatter T_h is that of the calibration session under res's model plus the full linear part
    (bias, scale, cross-axis; misalignment_tri for the norm): a model that misses a scale factor
    does not get its own misfit counted as scatter. An effect outside that reference (a warm-up,
    a temperature term) still inflates it: read heldout_chi2_dof beside the calibration's own
    chi2/dof (diagnose) and the noise-only value (predictive_stats). Holds are taken as independent:
    a slow drift common to many holds (flicker bias of 0.3 mg on an emulated hand-held session cut
    in halves) scores 2.5-3 where independent scatter of the same size scores ~1.

    scatter: a variance.HoldScatter to use instead of res's own (the common yardstick of a model
    comparison, variance.yardstick: every model judged with the same T_h, so an effect that lowers
    the held-out residual cannot score worse than its absence)."""
    from accellog.calibrate.model.variance import central_jacobian, hold_covariances, hold_groups, norm_system

    norm = res.method == "orientation_free" if norm is None else norm
    sigma_theta, sc = _calibration_uncertainty(res, scatter)
    if norm:
        h = norm_system(res, heldout, weighted=True)
        z, sig, Pw = h.e_g / h.sigma_g, h.sigma_g, h.J
    else:
        sig = np.asarray(heldout.sigma_g, float)
        z = predict_residual(res, heldout) / sig
        fun = lambda th: (predict_residual(res, heldout, th) / sig).ravel()  # noqa: E731
        Pw = central_jacobian(fun, np.asarray(res.theta, float), res.model.param_typical)
    groups = hold_groups(heldout)
    up = h.up if norm else np.asarray(heldout.up_sensor, float)
    Ts = (
        hold_covariances(up, z.shape[1], groups, sc)
        if sc is not None
        else [0 * np.eye(z.shape[1])] * len(groups)
    )
    return _woodbury_chi2(z, 1.0 / sig, Pw, sigma_theta, groups, Ts), float(np.sum(z**2)), z.size


def _calibration_uncertainty(res: FitResult, scatter=None):
    """(parameter covariance with the between-hold component, HoldScatter or None) of res on its own
    observations, the scatter given or from the reference fit (predictive_chi2); kept on res."""
    from accellog.calibrate.model.variance import component_cov, estimate_scatter

    if res.obs is None:
        return np.asarray(res.cov, float), scatter
    memo = res.derived
    if scatter is not None:
        key = ("predictive_cal", id(scatter))
        if key not in memo:
            memo[key] = (component_cov(res, res.obs, scatter), scatter)
        return memo[key]
    if "predictive_cal" not in memo:
        ref = _reference_fit(res)
        sc = estimate_scatter(ref, res.obs)
        memo["predictive_cal"] = (component_cov(res, res.obs, sc), sc)
    return memo["predictive_cal"]


def _reference_fit(res: FitResult) -> FitResult:
    """res's model plus the linear terms it lacks, fitted as res was (res itself when it has them all
    or the richer model cannot be fitted)."""
    from accellog.calibrate.model.fit import fit_model, fit_orientation_free
    from accellog.core.errors import AccellogError

    norm = res.method == "orientation_free"
    have = set(res.model.term_names)
    cross = {"cross_axis", "misalignment_tri"}
    add = [t for t in ("bias", "scale", "misalignment_tri" if norm else "cross_axis") if t not in have]
    add = [t for t in add if t not in cross or not have & cross]
    if not add:
        return res
    fit = fit_orientation_free if norm else fit_model
    if res.obs is None:  # the observations went with it: nothing to fit again
        return res
    try:
        return fit(res.obs, res.model.with_terms(add), weighted=res.weighted, gravity_g=res.gravity_g)
    except AccellogError:
        return res


def _woodbury_chi2(z, w, Pw, Sigma, groups, Ts) -> float:
    """z^T C^-1 z, C = I + Pw Sigma Pw^T + sum_h U_h T_h U_h^T (whitened; U_h rows w of hold h)."""
    n, per = z.shape

    def binv(X: np.ndarray) -> np.ndarray:  # B^-1 X per hold: I - U T (I + N T)^-1 U^T
        Y = X.reshape(n, per, -1).copy()
        for g, T in zip(groups, Ts, strict=True):
            if not np.any(T):
                continue
            wg = w[g][:, :, None]
            utx = np.sum(wg * Y[g], axis=0)  # (per, k)
            N = np.diag(np.sum(w[g] ** 2, axis=0))
            Y[g] -= wg * (T @ np.linalg.solve(np.eye(per) + N @ T, utx))[None]
        return Y.reshape(n * per, -1)

    zz = z.reshape(-1, 1)
    bz = binv(zz)
    chi2 = float(zz[:, 0] @ bz[:, 0])
    if Pw.shape[1] == 0:
        return chi2
    y = Pw.T @ bz[:, 0]
    M = Pw.T @ binv(Pw)
    return chi2 - float(y @ (Sigma @ np.linalg.solve(np.eye(M.shape[0]) + M @ Sigma, y)))


def predictive_heldout_score(
    res: FitResult, heldout: Sequence[ObsTable], *, norm: bool | None = None, kind: str = "heldout"
) -> Score:
    """Held-out chi2 per equation with the predictive covariance (predictive_chi2), pooled over the
    held-out sessions and per session (per_part): ~1 when the model transfers; how far above 1 says
    by how much it does not (compare Score.se)."""
    chi2, m, parts = 0.0, 0, []
    for h in heldout:
        c, _, k = predictive_chi2(res, h, norm=norm)
        chi2 += c
        m += k
        parts.append(c / max(k, 1))
    return Score(kind, chi2 / max(m, 1), m, parts)


def predictive_stats(
    res: FitResult, heldout: ObsTable, *, norm: bool | None = None, scatter=None
) -> dict[str, float]:
    """Held-out statistics of one session: heldout_chi2_dof (predictive, predictive_chi2; scatter:
    the common yardstick), heldout_chi2_dof_noise (window noise only), heldout_rms_g (residual RMS,
    g), heldout_noise_g (RMS of the window noise, g) and, with scatter, heldout_scatter_g (its RMS
    per equation, g)."""
    from accellog.calibrate.model.variance import norm_system

    norm = res.method == "orientation_free" if norm is None else norm
    c, c0, m = predictive_chi2(res, heldout, norm=norm, scatter=scatter)
    if norm:
        h = norm_system(res, heldout, weighted=True)
        e, sig = h.e_g, h.sigma_g
    else:
        e, sig = predict_residual(res, heldout), np.asarray(heldout.sigma_g, float)
    out = {
        "heldout_rms_g": float(np.sqrt(np.mean(e**2))),
        "heldout_noise_g": float(np.sqrt(np.mean(sig**2))),
        "heldout_chi2_dof": c / max(m, 1),
        "heldout_chi2_dof_noise": c0 / max(m, 1),
    }
    if scatter is not None:
        t = scatter.taus  # along (and across, twice): the per-equation mean of T_h's diagonal
        out["heldout_scatter_g"] = float(
            np.sqrt(t[0] ** 2 if len(t) == 1 else (t[0] ** 2 + 2 * t[1] ** 2) / 3)
        )
    return out


def block_groups(x: np.ndarray, k: int = N_BLOCKS) -> list[np.ndarray]:
    """Row indices of k contiguous blocks of x (quantiles), smallest x first."""
    order = np.argsort(np.asarray(x, float), kind="stable")
    return [np.sort(b) for b in np.array_split(order, k) if b.size]


def _whitened(res: FitResult, obs: ObsTable, norm: bool = False) -> tuple[np.ndarray, np.ndarray, int]:
    """(whitened Jacobian, whitened residual, equations per window) of res on its own obs: per axis
    (the fit's Jacobian, 3), or the gravity norm's (central differences, 1)."""
    if norm:
        e, s = norm_residual(res, obs)
        return _norm_jacobian(res, obs), e / s, 1
    sig = np.asarray(obs.sigma_g, float)
    J = res.jacobian
    assert J is not None, "a labelled fit keeps (or remakes) its Jacobian"
    if not res.weighted:
        J = J / sig.ravel()[:, None]
    return J, (res.residual_g / sig).ravel(), 3


def _norm_jacobian(res: FitResult, obs: ObsTable) -> np.ndarray:
    """d(e_r / sigma_n,r) / d theta by central differences (n windows x n_params)."""
    meas, drv, sig = np.asarray(obs.meas_g, float), obs_drivers(obs), _projected_sigma(obs)
    th = np.asarray(res.theta, float)

    def fun(t):
        return np.linalg.norm(res.model.correct(t, meas, drv), axis=1) / sig

    cols = []
    for k in range(th.size):
        h = 1e-6 * max(abs(th[k]), 1e-3)
        dp, dm = th.copy(), th.copy()
        dp[k] += h
        dm[k] -= h
        cols.append((fun(dp) - fun(dm)) / (2 * h))
    return np.column_stack(cols)


def block_cv(
    res: FitResult, obs: ObsTable, groups: Sequence[np.ndarray], *, norm: bool = False
) -> np.ndarray:
    """Chi2 of each block predicted from the others (inf where the others cannot determine it);
    norm: of the gravity-norm residual, one equation per window."""
    J, r, per = _whitened(res, obs, norm)
    return loo_chi2(J, r, groups, tol=1e-6, per=per)


def loo_chi2(
    J: np.ndarray, r: np.ndarray, groups: Sequence[np.ndarray], tol: float, per: int = 3
) -> np.ndarray:
    """Chi2 of each group of observations predicted by the fit to the others, in the p x p form.

    Whitened Jacobian J (per*n x p, rows obs-major, axis-minor; per = 3 axes, or 1 for the gravity
    norm) and residual r (per*n); group rows G,
    U = J_G (m x p), C = (J^T J)^+ = S S^T, G = U^T U. The m x m matrix I - U C U^T is never formed
    (push-through identity, valid for singular C):

        r_cv = (I - U C U^T)^-1 r_G = r_G + U C (I_p - G C)^-1 U^T r_G,

    and a group is predictable when min eig(I - U C U^T) = 1 - max eig(S^T G S) >= tol (the other
    eigenvalues are 1). Cost O(m p^2) per group: linear in the observations, memory O(m p).
    """
    C = np.linalg.pinv(J.T @ J)
    ev_c, vec_c = np.linalg.eigh(0.5 * (C + C.T))
    S = vec_c * np.sqrt(np.clip(ev_c, 0.0, None))
    eye = np.eye(J.shape[1])
    out = np.empty(len(groups))
    for k, g in enumerate(groups):
        rows = (np.asarray(g)[:, None] * per + np.arange(per)).ravel()
        U, rg = J[rows], r[rows]
        G = U.T @ U
        if 1.0 - np.linalg.eigvalsh(S.T @ G @ S).max() < tol:
            out[k] = np.inf
            continue
        rc = rg + U @ (C @ np.linalg.solve(eye - G @ C, U.T @ rg))
        out[k] = float(rc @ rc)
    return out


def blocking_drivers(obs: ObsTable) -> dict[str, np.ndarray]:
    """Drivers to cut into blocks: temperature (if it spans >= 1 degC) and time."""
    out: dict[str, np.ndarray] = {}
    T = obs.temp_degC
    if T is not None and np.all(np.isfinite(T)) and np.ptp(T) >= 1.0:
        out["temp_degC"] = np.asarray(T, float)
    out["t_s"] = np.asarray(obs.t_s, float)
    return out


def blocked_scores(
    fits: Mapping[str, FitResult], obs: ObsTable, k: int = N_BLOCKS, *, norm: bool = False
) -> dict[str, Score]:
    """Blocked validation of several fits of the same observations, compared on the blocks every
    fit can predict; pooled over the blocking drivers (temperature and time); norm: on the gravity
    norm (exposes a proxy that only fits one hand-held session's warm-up)."""
    per = 1 if norm else 3
    groups_all = {d: block_groups(x, k) for d, x in blocking_drivers(obs).items()}
    cv = {
        name: {d: block_cv(r, obs, g, norm=norm) for d, g in groups_all.items()} for name, r in fits.items()
    }
    kinds = "+".join(groups_all)
    out: dict[str, Score] = {}
    ok = {d: np.all([np.isfinite(cv[n][d]) for n in fits], axis=0) for d in groups_all}
    for name in fits:
        chi2, m, parts = 0.0, 0, []
        for d, groups in groups_all.items():
            for g, c, good in zip(groups, cv[name][d], ok[d], strict=True):
                if good:
                    chi2 += c
                    m += per * g.size
                    parts.append(c / (per * g.size))
        out[name] = Score(f"blocks:{kinds}", chi2 / m if m else np.nan, m, parts)
    return out


# ---------------------------------------------------------------------------------------------
# collinearity of candidates


def _effect_columns(
    res: FitResult, base: Model, obs: ObsTable, norm: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Whitened Jacobian columns of the terms not in `base` and of the base's terms."""
    J = _whitened(res, obs, norm)[0]
    extra = [i for i, n in enumerate(res.model.param_names) if n not in base.index]
    keep = [i for i, n in enumerate(res.model.param_names) if n in base.index]
    return J[:, extra], J[:, keep]


def _orth(A: np.ndarray) -> np.ndarray:
    if A.shape[1] == 0:
        return A
    U, s, _ = np.linalg.svd(A, full_matrices=False)
    return U[:, s > 1e-10 * max(s[0], 1e-300)]


def canonical_correlation(
    res_a: FitResult, res_b: FitResult, base: Model, obs: ObsTable, *, norm: bool = False
) -> float:
    """Largest canonical correlation between the (per-axis or, norm, gravity-norm) residual columns
    two candidates add to `base`, after projecting out the base model's columns (1 = one can
    replace the other on this data)."""
    Ea, Ba = _effect_columns(res_a, base, obs, norm)
    Eb, _ = _effect_columns(res_b, base, obs, norm)
    return added_columns_correlation(Ea, Eb, Ba)


def added_columns_correlation(Ea: np.ndarray, Eb: np.ndarray, B: np.ndarray) -> float:
    """Largest canonical correlation between the column spaces of Ea and Eb after projecting out
    the columns of B: cos of the smallest principal angle, in [0, 1] (0 if either space is empty)."""
    Qb = _orth(B)

    def perp(E):
        return E - Qb @ (Qb.T @ E) if Qb.size else E

    Qa, Qe = _orth(perp(Ea)), _orth(perp(Eb))
    if Qa.shape[1] == 0 or Qe.shape[1] == 0:
        return 0.0
    return float(np.clip(np.linalg.svd(Qa.T @ Qe, compute_uv=False)[0], 0.0, 1.0))


def driver_kind(effect: str, base: Model) -> str:
    """'temperature', 'time', 'orientation' (no driver signal) or 'user': what an effect follows."""
    e = all_effects(base.effects_file).get(effect)
    drivers = set(e.drivers) if e is not None else set()
    if drivers & {"temp_degC", "dtemp_degC_per_s"}:
        return "temperature"
    if drivers & {"t_s", "t_in_pose_s"}:
        return "time"
    return "orientation" if not drivers else "user"


def separating_recording(a: str, b: str, base: Model) -> str:
    """What to record so that effects a and b stop looking alike."""
    ka, kb = driver_kind(a, base), driver_kind(b, base)
    if {ka, kb} == {"temperature", "time"}:
        return (
            "a recording where temperature does not follow time: heat then cool, two soak "
            "temperatures, or a second session on another temperature path (--heldout)"
        )
    if ka == kb == "temperature":
        return "a wider temperature range with three or more soak temperatures (or heat then cool)"
    if ka == kb == "time":
        return "a longer session that repeats a pose at the start, the middle and the end"
    if "orientation" in (ka, kb):
        return "more orientations: cube edges and corners (45 deg tilts), each face at several yaws"
    return "a recording in which their driver signals vary independently"
