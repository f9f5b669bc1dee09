"""Between-hold scatter: honest parameter uncertainties when holds scatter more than the noise.

Windows inside one static hold share whatever disturbs that hold (placement of the sensor,
slow bias wander, thermal state), so they are not independent. Per axis a, hold h:

    r_w = e_w + u_h,  e_w ~ N(0, diag sigma_w^2) (window noise),  u_h ~ N(0, T_h) (between holds)
    T_h = tau_along^2 u u^T + tau_across^2 (I - u u^T)      (u: the hold's vertical, sensor frame)

Placement errors tilt the truth across gravity (tau_across); bias wander shows in every direction.
Each variance is the component that makes the chi2 of the hold means match its degrees of freedom
(Paule-Mandel / method of moments): rbar_h = weighted mean residual of hold h, v_h its noise
variance (1 / sum_w sigma_w^-2) in that direction, H holds, k parameters:

    sum_h (u . rbar_h)^2 / (v_h + tau_along^2) = H - k/3     (0 if already smaller at tau = 0)

and the same for the two across directions (per direction). chi2 = within-hold part
sum (r_w - rbar_h)^2 / sigma_w^2 plus the hold-mean terms at the estimated variances. The parameters stay the window-weighted estimate; their covariance
is the sandwich  cov = A^-1 (J_w^T V J_w) A^-1,  A = J_w^T J_w,  V = W^1/2 Sigma W^1/2 (whitened
Jacobian J_w, W = D^-1), and chi2 becomes sum_a Q_a(tau_a^2).

The alternative is a leave-one-hold-out jackknife: theta_(-h) = theta + (A - J_h^T J_h)^-1 J_h^T r_h
(one Gauss-Newton step, exact for linear models), cov = (H - 1) / H sum_h (theta_(-h) - mean)(...)^T,
over the holds whose removal leaves the model determined.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
from scipy import optimize, stats

from accellog.calibrate.fit import FitResult
from accellog.core.errors import ModelError
from accellog.core.session import ObsTable

METHODS = ("noise", "between_hold", "jackknife")
"""Uncertainty methods: window noise only (Cramer-Rao), plus a between-hold variance component,
or a leave-one-hold-out jackknife."""


@dataclass
class HoldScatter:
    """Between-hold standard deviation along gravity and across it (g), and the chi2 it implies."""

    tau_along_g: float
    tau_across_g: float
    chi2: float
    dof: int
    n_holds: int

    def to_dict(self) -> dict:
        return {
            "between_hold_along_g": float(self.tau_along_g),
            "between_hold_across_g": float(self.tau_across_g),
            "chi2": float(self.chi2),
            "dof": int(self.dof),
            "n_holds": int(self.n_holds),
        }


def hold_groups(obs: ObsTable) -> list[np.ndarray]:
    """Row indices of each hold (pose_id), in order of first appearance."""
    pid = np.asarray(obs.pose_id)
    _, first = np.unique(pid, return_index=True)
    return [np.flatnonzero(pid == pid[i]) for i in np.sort(first)]


def _paule_mandel(m2: np.ndarray, v: np.ndarray, dof: float) -> float:
    """tau^2 >= 0 with sum m2 / (v + tau^2) = dof (0 if the sum at tau = 0 is already <= dof)."""

    def q(t2: float) -> float:
        return float(np.sum(m2 / (v + t2)))

    if q(0.0) <= dof:
        return 0.0
    return float(optimize.brentq(lambda t2: q(t2) - dof, 0.0, float(np.sum(m2)) + 1e-30))


def _hold_frames(res: FitResult, obs: ObsTable) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per hold: (unit vertical u in the sensor frame, weighted mean residual (3,), its variance (3,))."""
    sig2 = np.asarray(obs.sigma_g, float) ** 2
    up = np.asarray(obs.up_sensor, float)
    out = []
    for g in hold_groups(obs):
        u = up[g].mean(axis=0)
        u = u / max(np.linalg.norm(u), 1e-12)
        c = np.sum(1.0 / sig2[g], axis=0)
        out.append((u, np.sum(res.residual_g[g] / sig2[g], axis=0) / c, 1.0 / c))
    return out


def estimate_scatter(res: FitResult, obs: ObsTable) -> HoldScatter:
    """Between-hold variances along gravity (tau_along) and across it (tau_across, per direction).

    Hold means rbar_h are split into the component along the hold's vertical u_h and the two across
    it (placement errors tilt the truth across gravity; bias wander shows in both); each variance
    solves Paule-Mandel with the hold-level degrees of freedom H - k/3 (along) and 2 (H - k/3)
    (across)."""
    frames = _hold_frames(res, obs)
    H, k = len(frames), res.model.n_params
    dof = max(H - k / 3.0, 1.0)
    along_m2 = np.array([float(u @ m) ** 2 for u, m, _ in frames])
    along_v = np.array([float(u**2 @ v) for u, _, v in frames])
    across_m2 = np.array([float(m @ m) - float(u @ m) ** 2 for u, m, _ in frames])
    across_v = np.array([float(np.sum(v)) - float(u**2 @ v) for u, _, v in frames]) / 2.0
    t_al = _paule_mandel(along_m2, along_v, dof)
    t_ac = _paule_mandel(across_m2 / 2.0, across_v, dof)  # mean over the two across directions
    # generalised chi2: within-hold part + hold means against noise + between-hold variance
    sig2 = np.asarray(obs.sigma_g, float) ** 2
    within = 0.0
    for g, (_, m, _) in zip(hold_groups(obs), frames, strict=True):
        within += float(np.sum((res.residual_g[g] - m) ** 2 / sig2[g]))
    chi2 = within + float(np.sum(along_m2 / (along_v + t_al)) + np.sum(across_m2 / (across_v + t_ac)))
    return HoldScatter(float(np.sqrt(t_al)), float(np.sqrt(t_ac)), chi2, res.residual_g.size - k, H)


def _whitened_jacobian(res: FitResult, obs: ObsTable) -> np.ndarray:
    if res.jacobian is None:
        raise ModelError("the fit has no Jacobian: between-hold uncertainties need a least-squares fit")
    J = res.jacobian
    if not res.weighted:
        J = J / np.asarray(obs.sigma_g, float).ravel()[:, None]
    return J


def component_cov(res: FitResult, obs: ObsTable, scatter: HoldScatter) -> np.ndarray:
    """Sandwich covariance of the window-weighted estimate with the between-hold component:
    J^T V J = J^T J + sum_h G_h^T T_h G_h,  G_h[a] = sum_{w in h} J_(w,a) / sigma_(w,a),
    T_h = tau_along^2 u u^T + tau_across^2 (I - u u^T)."""
    J = _whitened_jacobian(res, obs)
    A_inv = np.linalg.pinv(J.T @ J)
    w = 1.0 / np.asarray(obs.sigma_g, float)
    B = J.T @ J
    for g, (u, _, _) in zip(hold_groups(obs), _hold_frames(res, obs), strict=True):
        G = np.stack([w[g, a] @ J[g * 3 + a] for a in range(3)])
        uu = np.outer(u, u)
        T = scatter.tau_along_g**2 * uu + scatter.tau_across_g**2 * (np.eye(3) - uu)
        B = B + G.T @ T @ G
    return A_inv @ B @ A_inv


def jackknife_cov(res: FitResult, obs: ObsTable) -> tuple[np.ndarray, int]:
    """Leave-one-hold-out jackknife covariance (one Gauss-Newton step per hold) and holds used."""
    J = _whitened_jacobian(res, obs)
    r = (res.residual_g / np.asarray(obs.sigma_g, float)).ravel()
    A = J.T @ J
    thetas = []
    for g in hold_groups(obs):
        rows = (g[:, None] * 3 + np.arange(3)).ravel()
        Ah = A - J[rows].T @ J[rows]
        s = np.linalg.svd(Ah, compute_uv=False)
        if s[-1] < 1e-9 * s[0]:
            continue  # without this hold the model is not determined
        # theta_(-h) - theta = (A_h)^-1 J_h^T r_h  (J = d(residual)/d(theta); J^T r = 0 at the optimum)
        thetas.append(np.linalg.solve(Ah, J[rows].T @ r[rows]))
    H = len(thetas)
    if H < 3:
        raise ModelError(
            f"jackknife over holds needs >= 3 holds that can each be left out (have {H}): record more holds"
        )
    D = np.asarray(thetas)
    D = D - D.mean(axis=0)
    return (H - 1) / H * (D.T @ D), H


def with_uncertainty(res: FitResult, obs: ObsTable, method: str = "between_hold") -> FitResult:
    """A copy of `res` whose covariance, sigma and chi2 account for between-hold scatter
    (between_hold_g = [tau_along, tau_across] in g).

    method: 'noise' (unchanged), 'between_hold' (variance component) or 'jackknife' (leave one hold
    out; chi2 then keeps the noise-only value). The copy records the method and tau per axis.
    """
    if method not in METHODS:
        raise ModelError(f"unknown uncertainty method {method!r}; valid: {', '.join(METHODS)}")
    out = copy.copy(res)
    out.warnings = list(res.warnings)
    if method == "noise":
        return out
    sc = estimate_scatter(res, obs)
    out.between_hold_g = [sc.tau_along_g, sc.tau_across_g]
    if method == "between_hold":
        out.cov = component_cov(res, obs, sc)
        out.chi2 = sc.chi2
        out.chi2_dof = sc.chi2 / sc.dof if sc.dof > 0 else np.nan
        out.p_value = float(stats.chi2.sf(sc.chi2, sc.dof)) if sc.dof > 0 else np.nan
    else:
        out.cov, _ = jackknife_cov(res, obs)
    out.sigma = np.sqrt(np.clip(np.diag(out.cov), 0, None))
    out.sigma_scaled = out.sigma.copy()
    out.uncertainty = method
    return out
