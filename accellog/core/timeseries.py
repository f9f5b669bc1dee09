"""Time-series helpers shared by every layer: timestamp checks, boolean runs, cumulative trapezoid,
evenly spaced sample indices, windows of a series fed in blocks (``WindowCarry``), a straight-line
least-squares fit of points fed in blocks (``LineFit``)."""

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


MAX_GAP_S = 10.0
"""Longest step between samples (s) an integral is carried across; a longer one is a gap in the
recording (a logger paused, a bus lost): integrating through it would add unmeasured motion."""


def check_gap(t: np.ndarray, t_prev: float | None) -> None:
    """InputError naming the first step of t_s (s; from t_prev, the sample before, when given)
    longer than MAX_GAP_S."""
    full = t if t_prev is None else np.concatenate([[t_prev], t])
    steps = np.diff(full)
    if steps.size and float(np.max(steps)) > MAX_GAP_S:
        i = int(np.argmax(steps))
        t0 = float(full[i])
        raise InputError(
            f"a {float(steps[i]):.3g} s gap in the time stamps after t = {t0:.3f} s: the motion in it was not "
            f"measured, so nothing is integrated across it; take the part before it (evaluate, integrate, drift: "
            f"--until-s {t0:.6g})"
        )


def cumtrapz(
    t_s: np.ndarray,
    y: np.ndarray,
    start: np.ndarray | float | None = None,
    prev: tuple[float, np.ndarray] | None = None,
) -> np.ndarray:
    """Cumulative trapezoid integral of y (n,...) over t_s (n,) s, carried across blocks:

        I_i = I_{i-1} + (t_i - t_{i-1}) (y_i + y_{i-1}) / 2

    prev None: the series starts here, I_0 = start (None: 0; then scipy's cumulative_trapezoid with
    initial 0, bit for bit); prev = (t, y) of the previous block's last sample: the integral goes on
    from I = start there. The sums run in the order of one cumsum over the whole series, so a session
    fed block by block gives the bits of the whole session as one block. A step longer than
    MAX_GAP_S (from prev too) is an InputError naming it: the motion in a gap was not measured, so
    nothing is integrated across one."""
    y = np.asarray(y, float)
    t = np.asarray(t_s, float)
    check_gap(t, None if prev is None else float(prev[0]))
    shape = (-1,) + (1,) * (y.ndim - 1)
    out = np.empty_like(y)
    if prev is None:
        out[:1] = 0.0 if start is None else start
        if y.shape[0] > 1:
            s = np.diff(t).reshape(shape) * (y[1:] + y[:-1]) / 2.0
            if start is not None:
                s[0] += start
            np.cumsum(s, axis=0, out=out[1:])
        return out
    if y.shape[0] == 0:
        return out
    t_prev, y_prev = prev
    s = np.empty_like(y)
    np.add(y[0], y_prev, out=s[0])
    np.add(y[1:], y[:-1], out=s[1:])
    dt = np.empty(t.shape[0])
    dt[0] = t[0] - t_prev
    np.subtract(t[1:], t[:-1], out=dt[1:])
    s *= dt.reshape(shape)
    s /= 2.0
    if start is not None:
        s[0] += start
    np.cumsum(s, axis=0, out=out)
    return out


def sorted_unique(e: np.ndarray) -> np.ndarray:
    """np.unique of an already non-decreasing 1-D array, in one pass (np.unique sorts again, and in
    numpy 2 its first call imports numpy.ma: ~20 ms of a command's start)."""
    return e[np.concatenate([[True], e[1:] != e[:-1]])] if e.size else e


def even_indices(n: int, points: int) -> np.ndarray:
    """Indices of min(n, points) evenly spaced samples of n, the first and the last included, each once."""
    return sorted_unique(np.r_[np.linspace(0, n - 1, min(n, points)).astype(np.int64), n - 1])


class WindowCarry:
    """Cuts a series fed in blocks into the windows np.arange(t0, t_end, width) gives the whole series
    (``np.unique(np.searchsorted(t, edges))``), carrying the open window to the next block."""

    def __init__(self, width_s: float) -> None:
        self.width = float(width_s)
        self.t0: float | None = None
        self.carry: tuple[np.ndarray, ...] | None = None

    def push(self, t: np.ndarray, *cols: np.ndarray) -> tuple[np.ndarray, tuple, np.ndarray] | None:
        """(t, cols, starts) of the windows this block completes (None: none yet)."""
        if t.shape[0] == 0:
            return None
        t0 = self.t0 = float(t[0]) if self.t0 is None else self.t0
        if self.carry is not None:
            t = np.concatenate([self.carry[0], t])
            cols = tuple(np.concatenate([c, x]) for c, x in zip(self.carry[1:], cols, strict=True))
        edges = arange_above(t0, t[-1], self.width, t[0])
        starts = np.unique(np.concatenate([[0], np.searchsorted(t, edges)]))
        last = int(starts[-1])
        self.carry = (t[last:], *(c[last:] for c in cols))
        if starts.size < 2:
            return None
        return t[:last], tuple(c[:last] for c in cols), starts[:-1]

    def flush(self) -> tuple[np.ndarray, tuple, np.ndarray] | None:
        """The last (open) window: the series has ended."""
        if self.carry is None or self.carry[0].shape[0] == 0:
            return None
        t, *cols = self.carry
        self.carry = None
        return t, tuple(cols), np.zeros(1, dtype=int)


def arange_above(start: float, stop: float, step: float, lo: float) -> np.ndarray:
    """The elements > lo of np.arange(start, stop, step), the same floats, without making the ones
    before lo (a block late in a long session needs a few of the session's window edges, not all):
    numpy makes len ceil((stop - start) / step) values start, start + step, then start + i delta
    with delta = (start + step) - start."""
    n = max(int(np.ceil((stop - start) / step)), 0)
    delta = (start + step) - start
    i0 = min(max(int(np.floor((lo - start) / delta)) - 1, 0), n) if delta > 0 else 0
    edges = start + np.arange(i0, n, dtype=float) * delta
    for i, v in ((0, start), (1, start + step)):  # the two values numpy sets before its fill
        if i0 <= i < n:
            edges[i - i0] = v
    return edges[edges > lo]


class LineFit:
    """The least-squares line y = slope x + c of points fed in blocks, in memory bounded whatever
    their number: each block's centred sums merged into the running ones (Chan, Golub & LeVeque
    1979) about a reference line y0 = a0 x + c0 (the fit of the first REF_POINTS points), so the
    residual sum of squares is not lost to cancellation when the scatter is 1e-10 of the values
    (a day's host clock with microseconds of jitter); the values of a fit of all the points at
    once up to rounding:

        slope = a0 + Sxy / Sxx,   residual sum of squares = Syy - Sxy^2 / Sxx

    (S: sums of products of x and y - y0 about their means)."""

    REF_POINTS = 1000

    def __init__(self) -> None:
        self.n = 0
        self.mx = self.my = 0.0  # means of x and of y - y0(x)
        self.sxx = self.sxy = self.syy = 0.0
        self.ref: tuple[float, float] | None = None  # (a0, c0)
        self.pending: list[tuple[np.ndarray, np.ndarray]] = []
        self.n_pending = 0

    def add(self, x, y) -> None:
        x, y = np.asarray(x, float).ravel(), np.asarray(y, float).ravel()
        if x.shape[0] == 0:
            return
        if self.ref is None:
            self.pending.append((x, y))
            self.n_pending += x.shape[0]
            if self.n_pending >= self.REF_POINTS:
                self._settle()
            return
        self._fold(x, y - (self.ref[0] * x + self.ref[1]))

    def _settle(self) -> None:
        """Fix the reference line from the pending points and fold them in."""
        x = np.concatenate([p[0] for p in self.pending])
        y = np.concatenate([p[1] for p in self.pending])
        self.pending, self.n_pending = [], 0
        dx = x - x.mean()
        den = float(dx @ dx)
        a0 = float(dx @ (y - y.mean())) / den if den > 0 else 0.0
        self.ref = (a0, float(y.mean()) - a0 * float(x.mean()))
        self._fold(x, y - (a0 * x + self.ref[1]))

    def _fold(self, x: np.ndarray, y: np.ndarray) -> None:
        m = x.shape[0]
        mx, my = float(x.mean()), float(y.mean())
        dx, dy = x - mx, y - my
        n = self.n + m
        ex, ey = mx - self.mx, my - self.my
        w = self.n * m / n
        self.sxx += float(dx @ dx) + w * ex * ex
        self.sxy += float(dx @ dy) + w * ex * ey
        self.syy += float(dy @ dy) + w * ey * ey
        self.mx += ex * m / n
        self.my += ey * m / n
        self.n = n

    def _settled(self) -> LineFit:
        if self.ref is None and self.pending:
            self._settle()
        return self

    @property
    def count(self) -> int:
        """Points added."""
        return self.n + self.n_pending

    @property
    def slope(self) -> float:
        f = self._settled()
        return (f.ref[0] if f.ref else 0.0) + f.sxy / f.sxx if f.sxx > 0 else float("nan")

    @property
    def intercept(self) -> float:
        f = self._settled()
        a0, c0 = f.ref or (0.0, 0.0)
        return c0 + f.my - (f.slope - a0) * f.mx if f.sxx > 0 else float("nan")

    @property
    def spread(self) -> float:
        """Sxx: the sum of squares of x about its mean."""
        return self._settled().sxx

    @property
    def residual_ss(self) -> float:
        f = self._settled()
        return max(f.syy - f.sxy * f.sxy / f.sxx, 0.0) if f.sxx > 0 else float("nan")
