"""What a fit warns about: ArduPilot-like acceptance checks of a fitted calibration (scale within
0.8-1.2, |offset| < 1 g), residuals against the noise floor, parameters poorly determined, and
terms beyond the linear model that this data does not show (insignificant_terms)."""

from __future__ import annotations

import numpy as np

from accellog.calibrate.model.compose import Model
from accellog.calibrate.model.effects import AXES
from accellog.core.numeric import chi2_sf

STRUCTURAL = ("bias", "scale", "cross_axis", "misalignment_tri", "fixture_tilt")
"""Terms a calibration carries whether or not this data resolves them (the linear sensor model and
the fixture): not judged by insignificant_terms."""
SIGNIFICANT_P = 0.05


def acceptance_warnings(
    model: Model,
    S: np.ndarray,
    b: np.ndarray,
    chi2_dof: float,
    p: float,
    sigma: np.ndarray,
    weighted: bool,
    dof: int,
    noise_only: bool = True,
    *,
    theta: np.ndarray | None = None,
    cov: np.ndarray | None = None,
) -> list[str]:
    """ArduPilot-like acceptance checks as warnings (scale 0.8-1.2, |offset| < 1 g, residual vs noise;
    noise_only: sigma is the noise-only bound, and the warning says so); with theta and cov also
    the terms the data does not show (insignificant_terms)."""
    w: list[str] = []
    d = np.diag(S)
    for i, a in enumerate(AXES):
        if not 0.8 <= d[i] <= 1.2:
            w.append(f"scale of {a} = {d[i]:.4f} outside 0.8-1.2: wrong pose labels or axis signs?")
        if abs(b[i]) >= 1.0:
            w.append(f"offset of {a} = {b[i]:.3f} g exceeds 1 g: wrong pose labels or range?")
    if dof == 0:
        w.append("no degrees of freedom left: the fit interpolates the data, residuals say nothing")
    if np.isfinite(chi2_dof) and dof > 0 and chi2_dof > 3.0 and p < 1e-3:
        only = bool(weighted and noise_only)
        bound = "; parameter sigmas are the noise-only bound, see sigma_scaled" * only
        w.append(
            f"residuals are {np.sqrt(chi2_dof):.1f}x the noise floor (chi2/dof = {chi2_dof:.3g}): the model "
            f"misses an effect (run `accellog diagnose`){bound}"
        )
    for n, s, t in zip(model.param_names, sigma, model.param_typical, strict=True):
        if np.isfinite(s) and s > t:
            w.append(f"{n} poorly determined: 1-sigma {s:.3g} exceeds its typical size {t:.3g}")
    if theta is not None and cov is not None:
        w += insignificant_terms(model, theta, cov)
    return w


def insignificant_terms(model: Model, theta: np.ndarray, cov: np.ndarray) -> list[str]:
    """A sentence per term beyond STRUCTURAL whose effect this data does not show: the Wald test of
    its parameters at their 'absent' value 0, theta_t^T C_tt^+ theta_t ~ chi2(rank C_tt), has
    p > SIGNIFICANT_P (parameters that start elsewhere, e.g. a time constant, and parameters held
    fixed, sigma 0, are left out)."""
    out: list[str] = []
    off = model.initial_theta() == 0
    sig = np.sqrt(np.clip(np.diag(cov), 0, None))
    for name, sl in model.slices.items():
        idx = np.arange(sl.start, sl.stop)
        idx = idx[off[idx] & (sig[idx] > 0)]
        if name in STRUCTURAL or idx.size == 0:
            continue
        c = cov[np.ix_(idx, idx)]
        stat, k = (
            float(theta[idx] @ np.linalg.pinv(c, hermitian=True) @ theta[idx]),
            int(np.linalg.matrix_rank(c)),
        )
        p = chi2_sf(stat, k)
        if np.isfinite(p) and p > SIGNIFICANT_P:
            out.append(
                f"{name} is not significant on this data (Wald chi2 {stat:.3g} on {k} dof, p = {p:.2g}): its "
                "parameters are 0 within their uncertainty, so it adds uncertainty, and extrapolates, without "
                "explaining the residuals; refit without it (`accellog diagnose` says what this data shows)"
            )
    return out
