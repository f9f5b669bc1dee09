"""Small numerical kernels in numpy and math, so that the fit command does not import scipy
(scipy.optimize and scipy.special cost ~0.5-1 s of its start-up):

- ``least_squares``: Gauss-Newton / Levenberg-Marquardt with an exact Jacobian for problems of a few
  parameters, iterated to the optimum itself (until the Gauss-Newton step is at the rounding of the
  residuals), so the result does not depend on the path the iterations took;
- ``chi2_sf``: the chi-square survival function P(X > x), the regularised upper incomplete gamma
  function Q(k/2, x/2) (series / continued fraction, ~1e-14 relative).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass
class LsqResult:
    """Solution x, residuals fun = f(x) and Jacobian jac = J(x) at it, iterations taken."""

    x: np.ndarray
    fun: np.ndarray
    jac: np.ndarray
    nit: int


def least_squares(
    fun: Callable[[np.ndarray], np.ndarray],
    jac: Callable[[np.ndarray], np.ndarray],
    x0: np.ndarray,
    x_scale: float | np.ndarray = 1.0,
    *,
    rtol: float = 1e-12,
    max_iter: int = 100,
    jac0: np.ndarray | None = None,
) -> LsqResult:
    """min_x |fun(x)|^2 by Gauss-Newton steps, damped Levenberg-Marquardt style when a step raises
    the cost by more than rounding (lam * diag(1/x_scale^2), x 10 per try; steps by lstsq on the
    augmented Jacobian). Stops at the optimum to rounding: when the Gauss-Newton step is below
    rtol * max(|x|, x_scale) in every parameter, or is below 1e-9 of that and no longer shrinks
    (the rounding of the residuals), or no damped step lowers the cost. jac0: jac(x0) when known."""
    x = np.array(x0, float)
    scale = np.broadcast_to(np.asarray(x_scale, float), x.shape)
    r = np.asarray(fun(x), float)
    cost = float(r @ r)
    J = np.asarray(jac(x) if jac0 is None else jac0, float)
    nit, prev = 0, np.inf
    while nit < max_iter:
        nit += 1
        step = np.linalg.lstsq(J, -r, rcond=None)[0]
        size = float(np.max(np.abs(step) / np.maximum(np.abs(x), scale)))
        if size <= rtol or (size < 1e-9 and size > 0.5 * prev):
            break
        prev, lam, zeros = size, 0.0, np.zeros(x.size)
        while True:
            cand = x + step
            rc = np.asarray(fun(cand), float)
            cc = float(rc @ rc)
            if np.isfinite(cc) and cc <= cost * (1.0 + 1e-12):  # lower, or higher by rounding only
                break
            lam = 1e-6 if lam == 0.0 else lam * 10.0
            if lam > 1e16:
                return LsqResult(x, r, J, nit)
            damp = np.diag(np.sqrt(lam) / scale)
            step = np.linalg.lstsq(np.vstack([J, damp]), np.concatenate([-r, zeros]), rcond=None)[0]
        x, r, cost = cand, rc, cc
        J = np.asarray(jac(x), float)
    return LsqResult(x, r, J, nit)


_STIRLING = (1.0 / 12.0, -1.0 / 360.0, 1.0 / 1260.0, -1.0 / 1680.0, 1.0 / 1188.0, -691.0 / 360360.0)


def _log_prefactor(a: float, x: float) -> float:
    """log(x^a e^-x / Gamma(a)), formed without cancelling large terms for large a and x ~ a."""
    if a < 20.0:
        return a * math.log(x) - x - math.lgamma(a)
    # lgamma(a) = (a - 1/2) log a - a + log(2 pi)/2 + stirling(a); a log(x/a) + a - x = -a (d - log1p d)
    d = (x - a) / a
    stirling = sum(c / a ** (2 * k + 1) for k, c in enumerate(_STIRLING))
    return -a * (d - math.log1p(d)) + 0.5 * math.log(a / (2.0 * math.pi)) - stirling


def chi2_sf(x: float, k: float) -> float:
    """P(X > x) for X ~ chi-square with k > 0 degrees of freedom: Q(k/2, x/2) (module doc)."""
    a, z = 0.5 * float(k), 0.5 * float(x)
    if not (a > 0.0) or math.isnan(z):
        return math.nan
    if z <= 0.0:
        return 1.0
    if math.isinf(z):
        return 0.0
    pre = _log_prefactor(a, z)
    if z < a + 1.0:  # P by its series, Q = 1 - P
        term = total = 1.0 / a
        n = a
        while abs(term) > 1e-17 * abs(total):
            n += 1.0
            term *= z / n
            total += term
        return max(0.0, 1.0 - math.exp(pre) * total)
    # Q by its continued fraction (modified Lentz)
    tiny = 1e-300
    b = z + 1.0 - a
    c, d = 1.0 / tiny, 1.0 / b
    h = d
    for i in range(1, 100000):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = tiny if abs(d) < tiny else d
        c = b + an / c
        c = tiny if abs(c) < tiny else c
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < 1e-16:
            break
    return math.exp(pre) * h
