"""What a fit warns about: ArduPilot-like acceptance checks of a fitted calibration (scale within
0.8-1.2, |offset| < 1 g), residuals against the noise floor, parameters poorly determined."""

from __future__ import annotations

import numpy as np

from accellog.calibrate.model.compose import Model
from accellog.calibrate.model.effects import AXES


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
) -> list[str]:
    """ArduPilot-like acceptance checks as warnings (scale 0.8-1.2, |offset| < 1 g, residual vs noise;
    noise_only: sigma is the noise-only bound, and the warning says so)."""
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
    return w
