"""Time-series helpers shared by every layer: timestamp checks, boolean runs, cumulative trapezoid,
evenly spaced sample indices."""

from __future__ import annotations

import numpy as np

from accellog.core.errors import InputError


def check_time(t_s: np.ndarray, where: str | None = None) -> None:
    """InputError unless t_s (s) is 1-D, finite, strictly increasing and has >= 2 samples."""
    if t_s.ndim != 1 or t_s.shape[0] < 2:
        raise InputError("need at least 2 samples to integrate", where=where)
    if not np.all(np.isfinite(t_s)):
        raise InputError("timestamps contain NaN or infinite values", where=where)
    dt = np.diff(t_s)
    if np.any(dt <= 0):
        i = int(np.argmax(dt <= 0))
        raise InputError(
            f"timestamps not strictly increasing at sample {i + 1} (t = {t_s[i + 1]:.6f} s): they must increase",
            where=where,
        )


def runs(mask: np.ndarray) -> np.ndarray:
    """(K,2) [start, end) index pairs of the runs of True in a boolean mask."""
    d = np.diff(np.concatenate([[0], np.asarray(mask).astype(np.int8), [0]]))
    return np.stack([np.flatnonzero(d == 1), np.flatnonzero(d == -1)], axis=1)


def cumtrapz(t_s: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Cumulative trapezoid integral of y (n,...) over t_s (n,), starting at 0 at t_s[0]."""
    y = np.asarray(y, float)
    d = np.diff(np.asarray(t_s, float)).reshape((-1,) + (1,) * (y.ndim - 1))
    out = np.empty_like(y)
    out[:1] = 0.0
    np.cumsum(d * (y[1:] + y[:-1]) / 2.0, axis=0, out=out[1:])  # scipy's cumulative_trapezoid, bit for bit
    return out


def sorted_unique(e: np.ndarray) -> np.ndarray:
    """np.unique of an already non-decreasing 1-D array, in one pass (np.unique sorts again, and in
    numpy 2 its first call imports numpy.ma: ~20 ms of a command's start)."""
    return e[np.concatenate([[True], e[1:] != e[:-1]])] if e.size else e


def even_indices(n: int, points: int) -> np.ndarray:
    """Indices of min(n, points) evenly spaced samples of n, the first and the last included, each once."""
    return sorted_unique(np.r_[np.linspace(0, n - 1, min(n, points)).astype(np.int64), n - 1])
