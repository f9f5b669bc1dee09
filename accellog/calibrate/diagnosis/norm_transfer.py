"""Out-of-sample evidence for hand-held sessions (no pose labels): a model fitted orientation-free
on one session predicts the gravity norm of another session's static windows.

Per window r of the other session (its detected intervals, or its labelled holds: the norm needs
no orientation)

    e_r = |correct(theta; a'_r, drivers_r)| - g                    (g)
    sigma_n,r = |(a'_r / |a'_r|) . sigma_r|                         (noise projected on the reading)
    score = (1/m) sum_r (e_r / sigma_n,r)^2                          (chi2 per equation, m windows)

which is accellog.calibrate.diagnosis.transfer's held-out score with the orientation-free residual. Two
candidates are near-collinear when the whitened norm-residual Jacobian columns they add (after
projecting out the base model's) have a canonical correlation near 1 (transfer.COLLINEAR_RHO).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from accellog.calibrate.diagnosis.transfer import (
    Score,
    added_columns_correlation,
    blocked_scores,
    loo_chi2,
)
from accellog.calibrate.model.compose import Model
from accellog.calibrate.model.fit import FitResult, obs_drivers
from accellog.core.session import ObsTable


def _projected_sigma(obs: ObsTable) -> np.ndarray:
    meas = np.asarray(obs.meas_g, float)
    dirs = meas / np.linalg.norm(meas, axis=1, keepdims=True)
    return np.sqrt(np.sum((dirs * np.asarray(obs.sigma_g, float)) ** 2, axis=1))


def norm_residual(res: FitResult, obs: ObsTable) -> tuple[np.ndarray, np.ndarray]:
    """(e_r, sigma_n,r) in g of a fitted model on the windows of `obs` (module doc)."""
    f = res.model.correct(res.theta, np.asarray(obs.meas_g, float), obs_drivers(obs))
    return np.linalg.norm(f, axis=1) - res.gravity_g, _projected_sigma(obs)


def norm_heldout_score(res: FitResult, heldout: Sequence[ObsTable], kind: str = "heldout") -> Score:
    """chi2 per equation of the norm residual of `res` on every held-out session (pooled) and per
    session (per_part)."""
    chi2, m, parts = 0.0, 0, []
    for h in heldout:
        e, s = norm_residual(res, h)
        c = float(np.sum((e / s) ** 2))
        chi2 += c
        m += e.size
        parts.append(c / max(e.size, 1))
    return Score(kind, chi2 / max(m, 1), m, parts)


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


def norm_canonical_correlation(res_a: FitResult, res_b: FitResult, base: Model, obs: ObsTable) -> float:
    """Largest canonical correlation between the norm-residual columns two candidates add to
    `base` on `obs`, after projecting out the base model's columns (1: one replaces the other)."""

    def split(res):
        J = _norm_jacobian(res, obs)
        names = res.model.param_names
        extra = [i for i, n in enumerate(names) if n not in base.index]
        keep = [i for i, n in enumerate(names) if n in base.index]
        return J[:, extra], J[:, keep]

    Ea, Ba = split(res_a)
    Eb, _ = split(res_b)
    return added_columns_correlation(Ea, Eb, Ba)


def norm_block_cv(res: FitResult, obs: ObsTable, groups: Sequence[np.ndarray]) -> np.ndarray:
    """Chi2 of the gravity-norm residual e_r / sigma_n,r of each block of windows predicted from
    the others (calibrate.transfer.loo_chi2 with one equation per window; inf where the others
    cannot determine it)."""
    e, s = norm_residual(res, obs)
    return loo_chi2(_norm_jacobian(res, obs), e / s, groups, tol=1e-6, per=1)


def norm_blocked_scores(fits: dict[str, FitResult], obs: ObsTable) -> dict[str, Score]:
    """Blocked validation on the gravity norm within one hand-held session: blocks of the
    temperature range and of time, each predicted by the fit to the others (exposes a proxy that
    only fits this session's warm-up)."""
    return blocked_scores(fits, obs, cv_fn=norm_block_cv, per=1)
