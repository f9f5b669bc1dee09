"""Residual functions of the fits (accellog.calibrate.model.fit) and their Jacobians.

A residual function fun(theta) -> (m,) may offer `fun.analytic(theta) -> (J, columns left to
differences)` (calibrate.model.jacobian; a ``Residuals`` or a bound method of an object that has
one); numjac fills those columns (or all, without it) by central
differences. with_prior appends a prior's whitened rows (calibrate.model.prior); restricted holds
some parameters fixed.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from accellog.calibrate.model.prior import Prior
from accellog.core.numeric import jacobian_array

Vector = Callable[[np.ndarray], np.ndarray]
Analytic = Callable[[np.ndarray], "tuple[np.ndarray, list[int]] | None"]  # (J, columns to differences)


def _same(theta: np.ndarray) -> np.ndarray:
    return theta


@dataclass(frozen=True)
class Residuals:
    """A residual function with its analytic Jacobian (None: every column by differences) and, for
    a restriction to some parameters, full(x) -> the whole theta."""

    fun: Vector
    jacobian: Analytic | None = None
    full: Vector = _same

    def __call__(self, theta: np.ndarray) -> np.ndarray:
        return self.fun(theta)

    def analytic(self, theta: np.ndarray) -> tuple[np.ndarray, list[int]] | None:
        return None if self.jacobian is None else self.jacobian(theta)


def numjac(fun, theta: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Jacobian of fun: `fun.analytic(theta) -> (J, columns left to differences)` when offered
    (calibrate.model.jacobian), else central differences, column by column into one array."""
    got = _analytic(fun, theta)
    if got is not None:
        out, todo = got
        for k in todo:
            tp, tm = theta.copy(), theta.copy()
            tp[k] += steps[k]
            tm[k] -= steps[k]
            out[:, k] = (fun(tp) - fun(tm)) / (2.0 * steps[k])
        return out
    out = None
    for k in range(theta.size):
        tp = theta.copy()
        tm = theta.copy()
        tp[k] += steps[k]
        tm[k] -= steps[k]
        col = (fun(tp) - fun(tm)) / (2.0 * steps[k])
        out = jacobian_array(col.size, theta.size) if out is None else out
        out[:, k] = col
    return out if out is not None else np.zeros((fun(theta).size, 0))


def with_prior(fun, prior: Prior | None):
    """fun's residuals followed by the prior's whitened rows (its analytic Jacobian stacked on W)."""
    if prior is None:
        return fun

    def joined(theta):
        return np.concatenate([fun(theta), prior.rows(theta)])

    def analytic(theta):
        got = _analytic(fun, theta)
        return None if got is None else (np.vstack([got[0], prior.whiten]), got[1])

    return Residuals(joined, analytic)


def restricted(fun, theta0: np.ndarray, free: np.ndarray):
    """fun of the free parameters only (the others at theta0); .full(x) gives the whole theta."""
    idx = np.flatnonzero(free)

    def full(x):
        th = theta0.copy()
        th[idx] = x
        return th

    def sub(x):
        return fun(full(x))

    def analytic(x):
        got = _analytic(fun, full(x))
        if got is None:
            return None
        return got[0][:, idx], [int(np.searchsorted(idx, k)) for k in got[1] if free[k]]

    return Residuals(sub, analytic, full)


def _analytic(fun, theta: np.ndarray):
    """fun.analytic(theta) (or its bound object's), None when fun offers none."""
    analytic = getattr(fun, "analytic", None) or getattr(getattr(fun, "__self__", None), "analytic", None)
    return analytic(theta) if analytic is not None else None
