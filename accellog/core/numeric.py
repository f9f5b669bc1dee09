"""The one nonlinear least-squares solver of the fits, and the chi-square survival function, from scipy.

``least_squares`` is MINPACK's Levenberg-Marquardt through ``scipy.optimize.leastsq`` with tight
tolerances and its convergence verdict kept: a solve that stops without meeting a tolerance
(evaluation budget spent, improper input, non-finite residuals) is a one-line ModelError naming the
fit, never a silent result. ``chi2_sf`` is ``scipy.special.chdtrc``. scipy is imported inside the
functions, when a fit runs, not when the command line starts.

``leastsq`` and ``least_squares(method="lm")`` run the same MINPACK code (the accelerometer and gyro
fits came out bit for bit the same; a fit without a Jacobian, the magnetometer's, now takes
MINPACK's own forward differences, LMDIF, instead of scipy's). ``least_squares`` wraps the Jacobian
in a ``VectorFunction`` that hands MINPACK a copy of every evaluation and evaluates it once more at
the end, while MINPACK holds its own: up to five Jacobians at once. The 24 h benchmark session's
accelerometer fit (127k residuals x 13) peaked at 62 MB traced that way, 33 MB through ``leastsq``
(the fit's Jacobian and MINPACK's).

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
    and MINPACK's status (``info``) and message (status 1-4: a tolerance was met)."""

    x: np.ndarray
    fun: np.ndarray
    jac: np.ndarray
    nfev: int
    status: int
    message: str

    @property
    def converged(self) -> bool:
        return 1 <= self.status <= 4


def least_squares(
    fun: Callable[[np.ndarray], np.ndarray],
    x0: np.ndarray,
    *,
    what: str,
    jac: Callable[[np.ndarray], np.ndarray] | None = None,
    x_scale: float | np.ndarray | str = 1.0,
    tol: float = TOL,
    max_nfev: int | None = None,
) -> LsqResult:
    """min_x sum fun(x)^2 by MINPACK's Levenberg-Marquardt (scipy.optimize.leastsq: LMDER with the
    Jacobian jac, LMDIF's forward differences without) from x0 (x_scale: each parameter's typical
    size, or "jac"; max_nfev: leastsq's default when None). The Jacobian returned is
    jac(x) at the solution. Raises ModelError("<what> did not converge: ...") unless a tolerance
    was met with finite residuals."""
    from scipy.optimize import approx_fprime, leastsq

    x0 = np.asarray(x0, float)
    n = x0.size
    xz0, f0 = np.append(x0, 0.0), np.append(fun(x0), 0.0)  # (module docstring: the zero border)
    if not np.all(np.isfinite(f0)):
        raise ModelError(f"{what} did not converge: the residuals are not finite at the start")
    fun_z = _AtStart(lambda xz: np.append(fun(xz[:n]), 0.0), xz0, f0)
    jac_z = None if jac is None else _AtStart(lambda xz: _zero_border(jac(xz[:n])), xz0)
    diag = (
        None
        if isinstance(x_scale, str)
        else 1.0 / np.append(np.broadcast_to(np.asarray(x_scale, float), (n,)), 1.0)
    )
    try:
        xz, _, info, message, status = leastsq(
            fun_z, xz0, Dfun=jac_z, full_output=True, ftol=tol, xtol=tol, gtol=tol, maxfev=max_nfev or 0, diag=diag
        )  # fmt: skip
    except (ValueError, TypeError, np.linalg.LinAlgError) as exc:  # e.g. residuals of the wrong shape
        raise ModelError(f"{what} did not converge: {exc}") from None
    del info["fjac"], fun_z, jac_z  # MINPACK's factored Jacobian and the one kept: freed before jac(x)
    x, f = xz[:n], info["fvec"][:-1]
    J = (
        jac(x)
        if jac is not None
        else approx_fprime(x, fun, np.sqrt(np.finfo(float).eps) * np.maximum(1.0, np.abs(x)))
    )
    out = LsqResult(
        x, f, np.asarray(J, float), int(info["nfev"]), int(status), " ".join(str(message).split())
    )
    if not out.converged or not np.all(np.isfinite(out.fun)):
        why = out.message if not out.converged else "non-finite residuals at the solution"
        raise ModelError(f"{what} did not converge ({out.nfev} evaluations): {why}")
    return out


class _AtStart:
    """fn, with its value at the start x0 (value, or its first evaluation there) given again, not
    recomputed, while it is called there: leastsq checks the output's shape at x0 and MINPACK then
    starts there (one evaluation of the residuals and one of the Jacobian fewer). Dropped at the
    first call elsewhere."""

    def __init__(
        self, fn: Callable[[np.ndarray], np.ndarray], x0: np.ndarray, value: np.ndarray | None = None
    ):
        self.fn, self.value = fn, value
        self.x0: np.ndarray | None = x0

    def __call__(self, x: np.ndarray) -> np.ndarray:
        if self.x0 is not None:
            if np.array_equal(x, self.x0):
                if self.value is None:
                    self.value = self.fn(x)
                return self.value
            self.x0 = self.value = None
        return self.fn(x)


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


def chi2_ppf(q: float, k: np.ndarray) -> np.ndarray:
    """x with P(X <= x) = q for X ~ chi-square with k > 0 degrees of freedom (elementwise over k):
    scipy.special.chdtri(k, 1 - q), scipy.stats.chi2.ppf to ~1e-14 relative, without importing
    scipy.stats (~0.5 s of CPU)."""
    from scipy.special import chdtri

    return chdtri(np.asarray(k, float), 1.0 - q)


def f_sf(x: float, d1: float, d2: float) -> float:
    """P(X > x) for X ~ F(d1, d2) (scipy.special.fdtrc, as scipy.stats.f.sf: 1 for x <= 0, NaN for
    d1 or d2 <= 0) without importing scipy.stats (~0.8 s of CPU at start-up)."""
    from scipy.special import fdtrc

    return float(fdtrc(float(d1), float(d2), np.maximum(float(x), 0.0)))


def normal_sf(z: float) -> float:
    """P(Z > z) for a standard normal Z (scipy.special.ndtr(-z), as scipy.stats.norm.sf)."""
    from scipy.special import ndtr

    return float(ndtr(-float(z)))
