"""Leave-one-hold-out cross-validation of a fit: how well the other holds predict each hold.

Whitened residual r and Jacobian J; for hold g with rows G, r_cv = (I - H_GG)^-1 r_G with the hat
matrix H = J (J^T J)^+ J^T (exact for linear models, one Gauss-Newton step for nonlinear ones).
"""

from __future__ import annotations

import numpy as np

from accellog.calibrate.model.fit import FitResult
from accellog.core.session import ObsTable


def _groups(obs: ObsTable) -> list[np.ndarray]:
    """Row indices of each hold (pose_id)."""
    pid = np.asarray(obs.pose_id)
    return [np.flatnonzero(pid == g) for g in np.unique(pid)]


def cv_scores(res: FitResult, obs: ObsTable) -> np.ndarray:
    """Leave-one-hold-out chi2 of each hold (inf where the rest cannot predict it).

    Whitened residual r and Jacobian J (rows obs-major, axis-minor); for hold g with rows G:
    r_cv = (I - H_GG)^-1 r_G, H = J C J^T, C = (J^T J)^+. With U = J_G (m x p, m = 3 windows in
    the hold, p parameters) and G = U^T U (p x p), the m x m inverse is never formed
    (push-through identity, valid for singular C too):

        (I - U C U^T)^-1 = I + U C (I_p - G C)^-1 U^T,
        r_cv = r_G + U C (I_p - G C)^-1 U^T r_G,

    and the hold is predictable when min eig(I - U C U^T) = 1 - max eig(S^T G S) >= 1e-8
    (C = S S^T; the other eigenvalues of I - U C U^T are 1). Cost O(m p^2) per hold: linear in the
    windows. BLAS runs on one thread (these matrices are too small to gain from more).
    """
    J = res.jacobian
    sig = np.asarray(obs.sigma_g, float)
    r = (res.residual_g / sig).ravel()
    if J is None:
        return np.full(len(_groups(obs)), np.inf)
    if not res.weighted:  # jacobian of unweighted residuals: whiten it
        J = J / sig.ravel()[:, None]
    with _blas_controller().limit(limits=1, user_api="blas"):
        return _cv_small(J, r, _groups(obs))


def _blas_controller():
    """threadpoolctl's controller, made once (finding the BLAS libraries takes ~3 ms per call)."""
    global _BLAS
    if _BLAS is None:
        from threadpoolctl import ThreadpoolController

        _BLAS = ThreadpoolController()
    return _BLAS


_BLAS = None


def _cv_small(J: np.ndarray, r: np.ndarray, groups: list[np.ndarray]) -> np.ndarray:
    """cv_scores' per-hold loop in the p x p form (see there)."""
    C = np.linalg.pinv(J.T @ J)
    ev_c, vec_c = np.linalg.eigh(0.5 * (C + C.T))
    S = vec_c * np.sqrt(np.clip(ev_c, 0.0, None))  # C = S S^T
    eye = np.eye(J.shape[1])
    out = np.empty(len(groups))
    for k, g in enumerate(groups):
        rows = (g[:, None] * 3 + np.arange(3)).ravel()
        U, rg = J[rows], r[rows]
        G = U.T @ U
        if 1.0 - np.linalg.eigvalsh(S.T @ G @ S).max() < 1e-8:
            out[k] = np.inf
            continue
        rc = rg + U @ (C @ np.linalg.solve(eye - G @ C, U.T @ rg))
        out[k] = float(rc @ rc)
    return out


def cv_compare(cv_a: np.ndarray, cv_b: np.ndarray, obs: ObsTable) -> tuple[float, float, int]:
    """Mean CV chi2 per equation of models a and b over holds both can predict."""
    ok = np.isfinite(cv_a) & np.isfinite(cv_b)
    sizes = np.array([g.size * 3 for g in _groups(obs)])
    if not ok.any():
        return np.nan, np.nan, 0
    m = sizes[ok].sum()
    return float(cv_a[ok].sum() / m), float(cv_b[ok].sum() / m), int(ok.sum())
