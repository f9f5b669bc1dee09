"""Honest parameter uncertainties when holds scatter more than the noise.

Every method works on the residual the fit actually minimised (`fitted_system`):

- labelled fits: the per-axis residual e_(w,a) = meas - predict(theta, truth), 3 rows per window;
- orientation-free fits: the gravity-norm residual e_w = |S^-1 (a_w - b) ...| - g, 1 row per window
  (noise sigma_n,w = |(a_w / |a_w|) . sigma_w|); the truth directions are not parameters there.

Rows r = w e (w = 1/sigma when the fit was weighted, else 1), J = dr/dtheta, A = J^T J. Windows
inside one static hold share whatever disturbs that hold (placement, slow bias wander, hand
tremor), so they are not independent:

    e_w = eps_w + u_h,  eps_w ~ N(0, sigma_w^2) (window noise),  u_h ~ N(0, T_h) (between holds)
    labelled: T_h = tau_along^2 u u^T + tau_across^2 (I - u u^T)   (u: the hold's vertical)
    norm:     T_h = tau_along^2                                     (the norm sees only along-gravity)

Each tau^2 makes the chi2 of the hold means match its degrees of freedom (Paule-Mandel): rbar_h =
noise-weighted mean residual of hold h, v_h = its noise variance, H holds, k parameters, c
components per hold (3 labelled, 1 norm): sum_h (rbar_h)^2 / (v_h + tau^2) = H - k/c.

- 'noise': cov = A^-1 (J^T diag(s^2) J) A^-1 (s = w sigma; the Cramer-Rao bound when weighted),
  multiplied by the hold-mean Birge ratio Q0 / (c H - k) when the hold means reject the noise at
  p < NOISE_ALPHA (Q0 = sum_h rbar_h^2 / v_h): the bound is then not a bound, and says so;
- 'between_hold': the sandwich cov = A^-1 B A^-1, B = J^T diag(s^2) J + sum_h G_h^T T_h G_h,
  G_h[a] = sum_{w in h} w_(w,a) J_(w,a);
- 'jackknife': theta_(-h) = theta + (A - J_h^T J_h)^-1 J_h^T r_h (one Gauss-Newton step, exact for
  linear models, a refit's first step otherwise), cov = (H - 1) / H sum_h (theta_(-h) - mean)(..)^T
  over the holds whose removal leaves the model determined. `refit_jackknife_cov` refits instead.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from accellog.calibrate.model.acceptance import acceptance_warnings
from accellog.calibrate.model.fit import FitResult, fit_model, fit_orientation_free, obs_drivers
from accellog.core.errors import AccellogError, ModelError
from accellog.core.numeric import chi2_sf
from accellog.core.session import ObsTable

METHODS = ("noise", "between_hold", "jackknife")
"""Uncertainty methods: window noise (Cramer-Rao, scaled when the hold means reject it), plus a
between-hold variance component, or a leave-one-hold-out jackknife."""
NOISE_ALPHA = 0.01
"""The 'noise' sigma is scaled by the hold-mean Birge ratio when the hold means reject the noise
at this p-value (else it stays the Cramer-Rao bound)."""


@dataclass
class HoldScatter:
    """Between-hold standard deviation along gravity and across it (g; across is NaN for the
    gravity norm, which cannot see it), and the chi2 it implies."""

    tau_along_g: float
    tau_across_g: float
    chi2: float
    dof: int
    n_holds: int

    @property
    def taus(self) -> list[float]:
        """[tau_along, tau_across] (labelled) or [tau_along] (gravity norm), g."""
        return [self.tau_along_g] if np.isnan(self.tau_across_g) else [self.tau_along_g, self.tau_across_g]

    def to_dict(self) -> dict:
        return {
            "between_hold_along_g": float(self.tau_along_g),
            "between_hold_across_g": None if np.isnan(self.tau_across_g) else float(self.tau_across_g),
            "chi2": float(self.chi2),
            "dof": int(self.dof),
            "n_holds": int(self.n_holds),
        }


@dataclass
class FittedSystem:
    """The residual a fit minimised, by window: e_g (n, c) g, its noise sigma_g (n, c) g, the fit's
    weights w (n, c), J = d(w e)/dtheta (n c x k, rows window-major), unit verticals up (n, 3)."""

    J: np.ndarray
    e_g: np.ndarray
    sigma_g: np.ndarray
    w: np.ndarray
    up: np.ndarray

    @property
    def per(self) -> int:
        return int(self.e_g.shape[1])

    @property
    def r(self) -> np.ndarray:
        return (self.w * self.e_g).ravel()

    def rows(self, g: np.ndarray) -> np.ndarray:
        return (np.asarray(g)[:, None] * self.per + np.arange(self.per)).ravel()


def hold_groups(obs: ObsTable) -> list[np.ndarray]:
    """Row indices of each hold (pose_id), in order of first appearance."""
    pid = np.asarray(obs.pose_id)
    _, first = np.unique(pid, return_index=True)
    return [np.flatnonzero(pid == pid[i]) for i in np.sort(first)]


def central_jacobian(
    fun: Callable[[np.ndarray], np.ndarray], theta: np.ndarray, typical: np.ndarray
) -> np.ndarray:
    """d fun / d theta by central differences, steps max(1e-4 typical, 1e-7 |theta|) (as the fit's)."""
    steps = np.maximum(1e-4 * np.asarray(typical, float), 1e-7 * np.abs(theta))
    cols = []
    for k in range(theta.size):
        tp, tm = theta.copy(), theta.copy()
        tp[k] += steps[k]
        tm[k] -= steps[k]
        cols.append((fun(tp) - fun(tm)) / (2.0 * steps[k]))
    return np.column_stack(cols)


def norm_system(res: FitResult, obs: ObsTable, weighted: bool | None = None) -> FittedSystem:
    """The gravity-norm residual |correct(theta; a_w)| - g of `res` on the windows of `obs`, its
    projected noise sigma_n,w and Jacobian (weights 1/sigma_n when weighted, default res.weighted)."""
    meas = np.asarray(obs.meas_g, float)
    drv = obs_drivers(obs)
    dirs = meas / np.linalg.norm(meas, axis=1, keepdims=True)
    sig = np.sqrt(np.sum((dirs * np.asarray(obs.sigma_g, float)) ** 2, axis=1))[:, None]
    w = 1.0 / sig if (res.weighted if weighted is None else weighted) else np.ones_like(sig)

    def fun(th):
        return (np.linalg.norm(res.model.correct(th, meas, drv), axis=1) - res.gravity_g) * w[:, 0]

    f = res.model.correct(res.theta, meas, drv)
    e = (np.linalg.norm(f, axis=1) - res.gravity_g)[:, None]
    J = central_jacobian(fun, np.asarray(res.theta, float), res.model.param_typical)
    return FittedSystem(J, e, sig, w, f / np.linalg.norm(f, axis=1, keepdims=True))


def fitted_system(res: FitResult, obs: ObsTable, jacobian: bool = True) -> FittedSystem:
    """The residual `res` minimised on `obs` (labelled: per axis; orientation-free: gravity norm);
    jacobian=False: J left empty (labelled fits then do not remake a released Jacobian)."""
    if res.method == "orientation_free":
        return norm_system(res, obs)
    if not jacobian:
        J = np.zeros((0, res.model.n_params))
    elif res.jacobian is None:
        raise ModelError("the fit has no Jacobian: between-hold uncertainties need a least-squares fit")
    else:
        J = res.jacobian
    sig = np.asarray(obs.sigma_g, float)
    w = 1.0 / sig if res.weighted else np.ones_like(sig)
    up = np.asarray(obs.up_sensor, float)
    return FittedSystem(J, np.asarray(res.residual_g, float), sig, w, up)


def visit_groups(obs: ObsTable) -> list[np.ndarray]:
    """Row indices of each visit of a pose: a run of consecutive rows with one pose_id (a pose
    held again later is another visit)."""
    pid = np.asarray(obs.pose_id)
    if pid.size == 0:
        return []
    cuts = np.flatnonzero(pid[1:] != pid[:-1]) + 1
    return [np.arange(a, b) for a, b in zip(np.r_[0, cuts], np.r_[cuts, pid.size], strict=True)]


def _hold_means(
    sysm: FittedSystem, obs: ObsTable, visits: bool = False
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per hold (per visit when visits): (unit vertical u, noise-weighted mean residual (c,), its
    variance (c,))."""
    sig2 = sysm.sigma_g**2
    out = []
    for g in visit_groups(obs) if visits else hold_groups(obs):
        u = sysm.up[g].mean(axis=0)
        u = u / max(np.linalg.norm(u), 1e-12)
        c = np.sum(1.0 / sig2[g], axis=0)
        out.append((u, np.sum(sysm.e_g[g] / sig2[g], axis=0) / c, 1.0 / c))
    return out


def _paule_mandel(m2: np.ndarray, v: np.ndarray, dof: float) -> float:
    """tau^2 >= 0 with sum m2 / (v + tau^2) = dof (0 if the sum at tau = 0 is already <= dof)."""

    def q(t2: float) -> float:
        return float(np.sum(m2 / (v + t2)))

    if q(0.0) <= dof:
        return 0.0
    from scipy import optimize  # only when the holds scatter: `fit` starts without scipy

    return float(optimize.brentq(lambda t2: q(t2) - dof, 0.0, float(np.sum(m2)) + 1e-30))


def _components(frames, per: int) -> list[tuple[np.ndarray, np.ndarray, int]]:
    """(squared hold means, their noise variances, directions) along gravity and (labelled) across it."""
    if per == 1:
        return [(np.array([m[0] ** 2 for _, m, _ in frames]), np.array([v[0] for _, _, v in frames]), 1)]
    al_m2 = np.array([float(u @ m) ** 2 for u, m, _ in frames])
    al_v = np.array([float(u**2 @ v) for u, _, v in frames])
    ac_m2 = np.array([float(m @ m) for _, m, _ in frames]) - al_m2
    ac_v = np.array([float(np.sum(v)) - float(u**2 @ v) for u, _, v in frames])
    return [(al_m2, al_v, 1), (ac_m2, ac_v, 2)]


def estimate_scatter(res: FitResult, obs: ObsTable, sysm: FittedSystem | None = None) -> HoldScatter:
    """Between-hold variances of the fitted residual: along the hold's vertical u_h and across it
    (labelled), or of the gravity norm (orientation-free); Paule-Mandel with H - k/c degrees of
    freedom per direction (module doc)."""
    sysm = sysm or fitted_system(res, obs)
    frames = _hold_means(sysm, obs)
    H, k, per = len(frames), res.model.n_params, sysm.per
    dof = max(H - k / per, 1.0)
    taus, hold_chi2 = [], 0.0
    for m2, v, ndir in _components(frames, per):
        t2 = _paule_mandel(m2 / ndir, v / ndir, dof)  # across: mean over its two directions
        taus.append(t2)
        hold_chi2 += ndir * float(np.sum((m2 / ndir) / (v / ndir + t2)))
    within = 0.0  # generalised chi2: within-hold part + hold means against noise + tau
    for g, (_, m, _) in zip(hold_groups(obs), frames, strict=True):
        within += float(np.sum((sysm.e_g[g] - m) ** 2 / sysm.sigma_g[g] ** 2))
    across = float(np.sqrt(taus[1])) if per == 3 else np.nan
    return HoldScatter(float(np.sqrt(taus[0])), across, within + hold_chi2, sysm.e_g.size - k, H)


REPEAT_ANGLE_DEG = 10.0
"""Holds whose verticals lie within this angle are replicates of one orientation."""


def repeat_free_scatter(
    res: FitResult, obs: ObsTable, sysm: FittedSystem | None = None, max_angle_deg: float = REPEAT_ANGLE_DEG
) -> HoldScatter | None:
    """Between-hold scatter from what does not repeat and follows no driver: the visit means of the
    fitted residual are grouped by orientation (verticals within max_angle_deg; each visit of a pose
    is a hold), their deviations from their orientation's mean are freed of a straight line in the
    visit's temperature and time (a missing effect that follows a driver differs between visits at
    other temperatures: model error, not scatter), and what is left enters Paule-Mandel (dof: visits
    - orientations - regressors, per direction). A residual that repeats at the same orientation
    (nonlinearity, tilt) cancels in the deviations. None without enough replicates."""
    sysm = sysm or fitted_system(res, obs, jacobian=False)
    frames = _hold_means(sysm, obs, visits=True)
    visits = visit_groups(obs)
    cos_max = np.cos(np.radians(max_angle_deg))
    groups: list[list[int]] = []
    for i, (u, _, _) in enumerate(frames):
        for g in groups:
            if float(frames[g[0]][0] @ u) >= cos_max:
                g.append(i)
                break
        else:
            groups.append([i])
    reps = [g for g in groups if len(g) > 1]
    drivers = [np.asarray(obs.t_s, float)]
    if obs.temp_degC is not None and np.all(np.isfinite(obs.temp_degC)):
        drivers.append(np.asarray(obs.temp_degC, float))
    rows, dev = [], []
    for g in reps:
        n = len(g)  # plain means: the same centring for the residuals and their drivers
        mbar = np.mean([frames[i][1] for i in g], axis=0)
        vsum = np.sum([frames[i][2] for i in g], axis=0)
        x = np.array([[float(np.mean(d[visits[i]])) for d in drivers] for i in g])
        rows.append(x - x.mean(axis=0))
        for i in g:
            u, m, v = frames[i]
            dev.append((u, m - mbar, v * (1.0 - 2.0 / n) + vsum / n**2))  # the deviation's noise
    if not dev:
        return None
    X = np.vstack(rows)
    X = X[:, np.ptp(X, axis=0) > 0] if X.size else X
    p = X.shape[1]
    dof = sum(len(g) - 1 for g in reps) - p
    if dof < 1:
        return None
    D = np.array([d for _, d, _ in dev])  # (n, c) deviations
    if p:
        coef, *_ = np.linalg.lstsq(X / np.std(X, axis=0), D, rcond=None)
        D = D - (X / np.std(X, axis=0)) @ coef  # the part that follows temperature or time removed
    dev = [(u, d, v) for (u, _, v), d in zip(dev, D, strict=True)]
    taus, chi2 = [], 0.0
    for m2, v, ndir in _components(dev, sysm.per):
        t2 = _paule_mandel(m2 / ndir, np.maximum(v / ndir, 1e-300), float(dof))
        taus.append(t2)
        chi2 += ndir * float(np.sum((m2 / ndir) / (v / ndir + t2)))
    across = float(np.sqrt(taus[1])) if sysm.per == 3 else np.nan
    return HoldScatter(float(np.sqrt(taus[0])), across, chi2, int(dof), len(frames))


def yardstick(res: FitResult, obs: ObsTable) -> tuple[HoldScatter, str]:
    """(the between-hold scatter every model of one comparison is judged with, where it came
    from): repeat_free_scatter of the richest model's residual, or, without replicate holds, that
    model's estimate_scatter ('model residual': a missing effect can still inflate it)."""
    sc = repeat_free_scatter(res, obs)
    if sc is not None:
        return sc, "replicates"
    return estimate_scatter(res, obs), "model residual"


def hold_birge(res: FitResult, obs: ObsTable, sysm: FittedSystem | None = None) -> tuple[float, float, int]:
    """(Q0 / dof, p-value, dof) of the hold means against the window noise: Q0 = sum_h rbar_h^2 / v_h
    over every component, dof = c H - k (NaN when dof < 1)."""
    sysm = sysm or fitted_system(res, obs, jacobian=False)
    frames = _hold_means(sysm, obs)
    dof = sysm.per * len(frames) - res.model.n_params
    if dof < 1:
        return np.nan, np.nan, dof
    q0 = float(sum(np.sum(m**2 / v) for _, m, v in frames))
    return q0 / dof, float(chi2_sf(q0, dof)), dof


def hold_covariances(
    up: np.ndarray, per: int, groups: list[np.ndarray], scatter: HoldScatter
) -> list[np.ndarray]:
    """T_h (per x per, g^2) of each hold (rows `groups` of the unit verticals up): tau_along^2 u u^T
    + tau_across^2 (I - u u^T) per axis (per = 3), or tau_along^2 for the gravity norm (per = 1)."""
    if per == 1:
        return [np.array([[scatter.tau_along_g**2]]) for _ in groups]
    out = []
    for g in groups:
        u = up[g].mean(axis=0)
        u = u / max(np.linalg.norm(u), 1e-12)
        uu = np.outer(u, u)
        out.append(scatter.tau_along_g**2 * uu + scatter.tau_across_g**2 * (np.eye(3) - uu))
    return out


def component_cov(
    res: FitResult, obs: ObsTable, scatter: HoldScatter, sysm: FittedSystem | None = None
) -> np.ndarray:
    """Sandwich covariance of the fitted estimate with the between-hold component (module doc)."""
    sysm = sysm or fitted_system(res, obs)
    J, per = sysm.J, sysm.per
    A_inv = np.linalg.pinv(J.T @ J)
    s = (sysm.w * sysm.sigma_g).ravel()
    B = (J * s[:, None] ** 2).T @ J
    groups = hold_groups(obs)
    for g, T in zip(groups, hold_covariances(sysm.up, per, groups, scatter), strict=True):
        G = np.stack([sysm.w[g, a] @ J[g * per + a] for a in range(per)])
        B = B + G.T @ T @ G
    return A_inv @ B @ A_inv


def jackknife_cov(res: FitResult, obs: ObsTable, sysm: FittedSystem | None = None) -> tuple[np.ndarray, int]:
    """Leave-one-hold-out jackknife covariance (one Gauss-Newton step per hold on the fitted
    residual) and the number of holds used."""
    sysm = sysm or fitted_system(res, obs)
    J, r = sysm.J, sysm.r
    A = J.T @ J
    thetas = []
    for g in hold_groups(obs):
        rows = sysm.rows(g)
        Ah = A - J[rows].T @ J[rows]
        s = np.linalg.svd(Ah, compute_uv=False)
        if s[-1] < 1e-9 * s[0]:
            continue  # without this hold the model is not determined
        thetas.append(np.linalg.solve(Ah, J[rows].T @ r[rows]))
    return _jack(np.asarray(thetas))


def _jack(thetas: np.ndarray) -> tuple[np.ndarray, int]:
    H = len(thetas)
    if H < 3:
        raise ModelError(
            f"jackknife over holds needs >= 3 holds that can each be left out (have {H}): record more holds"
        )
    D = thetas - thetas.mean(axis=0)
    return (H - 1) / H * (D.T @ D), H


def obs_rows(obs: ObsTable, keep: np.ndarray) -> ObsTable:
    """The windows of `obs` where `keep` (bool mask or indices); pose names kept."""
    kw = {}
    for name, v in vars(obs).items():
        kw[name] = v[keep] if isinstance(v, np.ndarray) and v.shape[:1] == (obs.n,) else v
    return ObsTable(**kw)


def refit_jackknife_cov(
    res: FitResult, obs: ObsTable, fit_fn: Callable[..., FitResult]
) -> tuple[np.ndarray, int]:
    """Leave-one-hold-out jackknife by full refits: fit_fn(obs without hold h, res.model,
    weighted=..., gravity_g=...) for every hold (holds whose removal leaves the model undetermined
    are skipped); (cov, holds used). The reference the one-step jackknife is checked against."""
    thetas = []
    for g in hold_groups(obs):
        keep = np.ones(obs.n, bool)
        keep[g] = False
        try:
            r = fit_fn(obs_rows(obs, keep), res.model, weighted=res.weighted, gravity_g=res.gravity_g)
        except AccellogError:
            continue
        thetas.append(r.theta)
    return _jack(np.asarray(thetas))


def with_uncertainty(res: FitResult, obs: ObsTable, method: str = "between_hold") -> FitResult:
    """A copy of `res` whose covariance, sigma, warnings and uncertainty_note follow `method`
    ('noise', 'between_hold' or 'jackknife'; module doc), all from the residual the fit minimised.
    between_hold: chi2 becomes the generalised chi2 with the between-hold variances; the copy
    records tau (between_hold_g: [along, across] g, or [along] for the gravity norm)."""
    if method not in METHODS:
        raise ModelError(f"unknown uncertainty method {method!r}; valid: {', '.join(METHODS)}")
    out = copy.copy(res)
    out.uncertainty = method
    kind = "gravity-norm" if res.method == "orientation_free" else "per-axis"
    if method == "noise":
        _noise(out, res, obs, kind)
        return out
    sysm = fitted_system(res, obs)
    sc = estimate_scatter(res, obs, sysm)
    out.between_hold_g = sc.taus
    if method == "between_hold":
        out.cov = component_cov(res, obs, sc, sysm)
        out.chi2 = sc.chi2
        out.chi2_dof = sc.chi2 / sc.dof if sc.dof > 0 else np.nan
        out.p_value = float(chi2_sf(sc.chi2, sc.dof)) if sc.dof > 0 else np.nan
        taus = "/".join(f"{t * 1e3:.3g}" for t in sc.taus)
        out.uncertainty_note = (
            f"window noise plus a between-hold variance component ({taus} mg"
            f"{' along/across gravity' if len(sc.taus) == 2 else ' in the norm'}; {kind} residual)"
        )
    else:
        out.cov, H = jackknife_cov(res, obs, sysm)
        out.uncertainty_note = f"leave-one-hold-out jackknife over {H} holds ({kind} residual)"
    _finish(out, noise_only=False)
    return out


def fit_with_uncertainty(
    obs: ObsTable, m, *, orientation_free: bool, weighted: bool, gravity_g: float, uncertainty: str
) -> FitResult:
    """The fit of obs (orientation-free on the gravity norm, or labelled per axis) with the
    uncertainty asked (with_uncertainty; 'noise' too: scaled when the holds reject it)."""
    if orientation_free:
        fit = fit_orientation_free(obs, m, weighted=weighted, gravity_g=gravity_g)
    else:
        fit = fit_model(obs, m, weighted=weighted, gravity_g=gravity_g)
    return with_uncertainty(fit, obs, uncertainty)


def _noise(out: FitResult, res: FitResult, obs: ObsTable, kind: str) -> None:
    """'noise': the Cramer-Rao bound (unweighted: s^2 (J^T J)^-1, s^2 = the window residual
    variance), scaled by the hold-mean Birge ratio when the holds reject it (unweighted: hold means
    judged against s^2 / windows)."""
    base = "window noise" if res.weighted else "window residual scatter"
    out.uncertainty_note = (
        f"window noise only (Cramer-Rao bound, {kind} residual)"
        if res.weighted
        else f"residual scatter of the unweighted fit, windows independent ({kind} residual)"
    )
    try:
        sysm = fitted_system(res, obs, jacobian=False)
        if not res.weighted:  # the unweighted fit's noise model: every residual has variance s^2
            s2 = float(np.sum(sysm.e_g**2)) / max(sysm.e_g.size - res.model.n_params, 1)
            sysm.sigma_g = np.full_like(sysm.e_g, np.sqrt(s2))
        ratio, p, dof = hold_birge(res, obs, sysm)
    except ModelError:
        return
    if not (np.isfinite(p) and p < NOISE_ALPHA and ratio > 1.0):
        return
    out.cov = res.cov * ratio
    out.uncertainty_note = (
        f"{base} x {np.sqrt(ratio):.3g}: the hold means scatter beyond it "
        f"(chi2/dof {ratio:.3g} over {dof} dof; {kind} residual)"
    )
    _finish(out, noise_only=False)
    out.warnings.append(
        f"1-sigma = {out.uncertainty_note}; --uncertainty between_hold or jackknife model the scatter"
    )


def _finish(out: FitResult, noise_only: bool) -> None:
    """sigma and the acceptance warnings from out.cov (one covariance behind every printed sigma)."""
    out.sigma = np.sqrt(np.clip(np.diag(out.cov), 0, None))
    out.sigma_scaled = out.sigma.copy()
    out.warnings = acceptance_warnings(
        out.model,
        out.S,
        out.b,
        out.chi2_dof,
        out.p_value,
        out.sigma,
        out.weighted,
        out.dof,
        noise_only=noise_only,
        theta=out.theta,
        cov=out.cov,
    )
