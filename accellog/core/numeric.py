"""The one nonlinear least-squares solver of the fits, and the chi-square survival function, from scipy.

``least_squares`` is ``scipy.optimize.least_squares`` (MINPACK's Levenberg-Marquardt, ``method="lm"``)
with tight tolerances and its convergence verdict kept: a solve that stops without meeting a
tolerance (evaluation budget spent, improper input, non-finite residuals) is a one-line ModelError
naming the fit, never a silent result. ``chi2_sf`` is ``scipy.special.chdtrc``. scipy is imported
inside the functions, when a fit runs, not when the command line starts.

Bit-for-bit repeatable: MINPACK's QR (scipy 1.17's C translation of qrfac) recomputes the norm of a
column whose remaining norm cancelled below ~7e-8 of its start (nearly collinear columns, e.g. a
warm-up whose tau is far below the observation times, where w and the bias cancel) with one element
too many; for the last column that element lies past the end of the Jacobian buffer, so the pivot
order, the path and the result (chi2 from its 7th digit, about 1 fresh process in 4 on such a fit)
depended on whatever the heap held there (valgrind: "Invalid read of size 8 ... 0 bytes after a
block" in enorm <- qrfac <- LMDER). The solver is handed one extra, last parameter that the
residuals ignore (an all-zero Jacobian column): MINPACK's pivoting never moves a zero-norm column and
never recomputes its norm, so every read stays inside the buffer; the parameter stays at 0 and is
dropped from the result. One extra residual, always 0 (a zero row: exact no-op in MINPACK's sums),
keeps a fit with as many residuals as parameters solvable. The extra column makes MINPACK take its
rank-deficient branch: accelerometer calibrations checked came out byte for byte the same, the gyro
fit moved by up to 3e-10 relative (inside its tolerance).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from accellog.core.errors import ModelError

TOL = 1e-12
"""ftol = xtol = gtol of every fit: relative change of the cost, of the scaled parameters, and the
scaled gradient at which MINPACK stops (the fits' tolerance since they used MINPACK; scipy's default is 1e-8).
Tighter tolerances do not move the fits: MINPACK then stops where the cost no longer changes in the
last digits, ~1e-10 (relative) of the parameters from where the gradient vanishes."""


@dataclass
class LsqResult:
    """Solution x, residuals fun = f(x) and Jacobian jac = J(x) at it, function evaluations nfev,
    and scipy's status and message (status 1-4: a tolerance was met)."""

    x: np.ndarray
    fun: np.ndarray
    jac: np.ndarray
    nfev: int
    status: int
    message: str

    @property
    def converged(self) -> bool:
        return self.status > 0


def least_squares(
    fun: Callable[[np.ndarray], np.ndarray],
    x0: np.ndarray,
    *,
    what: str,
    jac: Callable[[np.ndarray], np.ndarray] | str = "2-point",
    x_scale: float | np.ndarray | str = 1.0,
    tol: float = TOL,
    max_nfev: int | None = None,
) -> LsqResult:
    """min_x sum fun(x)^2 by scipy.optimize.least_squares(method="lm") from x0 (x_scale: each
    parameter's typical size, or "jac"; max_nfev: scipy's default 100 n with a callable jac).
    Raises ModelError("<what> did not converge: ...") unless a tolerance was met with finite
    residuals."""
    from scipy.optimize import least_squares as scipy_least_squares

    x0 = np.asarray(x0, float)
    n = x0.size
    fun_z = lambda xz: np.append(fun(xz[:n]), 0.0)  # noqa: E731  (module docstring)
    jac_z = jac if isinstance(jac, str) else (lambda xz: _zero_border(jac(xz[:n])))
    if not isinstance(x_scale, str):
        x_scale = np.append(np.broadcast_to(np.asarray(x_scale, float), (n,)), 1.0)
    try:
        sol = scipy_least_squares(
            fun_z, np.append(x0, 0.0), jac=jac_z, method="lm", x_scale=x_scale,
            ftol=tol, xtol=tol, gtol=tol, max_nfev=max_nfev,
        )  # fmt: skip
    except (ValueError, np.linalg.LinAlgError) as exc:  # e.g. non-finite residuals at x0
        raise ModelError(f"{what} did not converge: {exc}") from None
    x, f, J = sol.x[:n], sol.fun[:-1], sol.jac[:-1, :n]
    out = LsqResult(x, f, J, int(sol.nfev), int(sol.status), str(sol.message))
    if not out.converged or not np.all(np.isfinite(out.fun)):
        why = out.message if not out.converged else "non-finite residuals at the solution"
        raise ModelError(f"{what} did not converge ({out.nfev} evaluations): {why}")
    return out


def load_solver() -> None:
    """Import the solver now (scipy.optimize, ~0.15-0.3 s of CPU), not on the first fit."""
    import scipy.optimize  # noqa: F401


def solver_loaded() -> bool:
    """Whether the solver's import is done (load_solver has nothing left to do)."""
    return "scipy.optimize" in sys.modules


def jacobian_array(m: int, n: int) -> np.ndarray:
    """A zeroed (m, n) float array to build a Jacobian in: the top-left block of an (m + 1, n + 1)
    array whose last row and column stay zero, which ``least_squares`` hands to MINPACK as it is
    (module docstring) instead of a bordered copy (a 24 h fit: 13 MB less at its peak)."""
    return np.zeros((m + 1, n + 1))[:-1, :-1]


def _zero_border(J: np.ndarray) -> np.ndarray:
    """J (m, n) with an all-zero row and column appended (m + 1, n + 1): the array J was cut from
    when it is a ``jacobian_array`` (its border still zero), else a copy."""
    J = np.asarray(J, float)
    base = J.base
    if (
        isinstance(base, np.ndarray)
        and base.shape == (J.shape[0] + 1, J.shape[1] + 1)
        and base.dtype == J.dtype
        and base.flags.c_contiguous
        and J.strides == base.strides
        and J.__array_interface__["data"][0] == base.__array_interface__["data"][0]
        and not base[-1].any()
        and not base[:, -1].any()
    ):
        return base
    out = np.zeros((J.shape[0] + 1, J.shape[1] + 1))
    out[:-1, :-1] = J
    return out


def chi2_sf(x: float, k: float) -> float:
    """P(X > x) for X ~ chi-square with k > 0 degrees of freedom (scipy.special.chdtrc); NaN for k <= 0."""
    if not k > 0:
        return math.nan
    from scipy.special import chdtrc

    return float(chdtrc(float(k), float(x)))


def f_sf(x: float, d1: float, d2: float) -> float:
    """P(X > x) for X ~ F(d1, d2) (scipy.special.fdtrc, as scipy.stats.f.sf: 1 for x <= 0, NaN for
    d1 or d2 <= 0) without importing scipy.stats (~0.8 s of CPU at start-up)."""
    from scipy.special import fdtrc

    return float(fdtrc(float(d1), float(d2), np.maximum(float(x), 0.0)))


def normal_sf(z: float) -> float:
    """P(Z > z) for a standard normal Z (scipy.special.ndtr(-z), as scipy.stats.norm.sf)."""
    from scipy.special import ndtr

    return float(ndtr(-float(z)))
