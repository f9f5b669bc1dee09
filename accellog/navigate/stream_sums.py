"""Running sums of a static residual fed block by block: the statistics `evaluate` reports, in memory
bounded independently of the session length, equal to the whole-series formulas up to rounding.

For a residual series r_i (m/s^2, i = 0..n-1, times t_i s) fed in consecutive blocks:

- mean and std (ddof 1) from shifted sums S1 = sum (r - c), S2 = sum (r - c)^2 (c: the first
  block's mean, so no cancellation);
- the integrated autocorrelation time (``calibrate.observe.hold_noise.AutocorrTime``: summed block
  spectra corrected for the global mean at the end);
- windows [t0 + k w, t0 + (k+1) w) exactly as ``np.arange(t0, t_end, w)`` cuts the whole series (the
  open window is carried to the next block);
- v(t), d(t): the cumulative trapezoid rule carried across blocks (``core.timeseries.cumtrapz``:
  v_i = v_{i-1} + dt (a_i + a_{i-1}) / 2, the bits of the whole session as one block), read at
  requested times by linear interpolation between samples.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from accellog.calibrate.observe.hold_noise import AutocorrTime
from accellog.core.timeseries import WindowCarry, cumtrapz


class Integrator:
    """v = cumtrapz(t, a), d = cumtrapz(t, v) carried across blocks; values at requested times."""

    def __init__(self, times_s: Sequence[float], tolerance_s: float = 0.5) -> None:
        self.req = np.asarray(times_s, float)
        self.tol = tolerance_s
        self.used = np.full(self.req.shape, np.nan)
        self.at: dict[str, np.ndarray] = {}
        # of the last sample: t (float, s); a, v, d and end_<series> ((3,) arrays)
        self.last: dict[str, Any] | None = None
        self.t0: float | None = None
        self.brackets: dict[
            int, tuple[np.ndarray, np.ndarray]
        ] = {}  # time index: the samples (t, d) around it

    def add(
        self, t: np.ndarray, a: np.ndarray, extra: Callable[[np.ndarray, np.ndarray], dict] | None = None
    ) -> tuple[np.ndarray, np.ndarray, dict]:
        """(v, d, extra series) of this block; extra(t, d) -> {name: (m,3)} series also read at times."""
        if t.shape[0] == 0:
            z = np.zeros((0, 3))
            return z, z, {}
        if self.last is None:
            self.t0 = float(t[0])
            v = cumtrapz(t, a)
            d = cumtrapz(t, v)
        else:
            last = self.last
            v = cumtrapz(t, a, last["v"], prev=(last["t"], last["a"]))
            d = cumtrapz(t, v, last["d"], prev=(last["t"], last["v"]))
        series = {"d": d, **(extra(t, d) if extra is not None else {})}
        self._read_at(t, series)
        self.last = {"t": float(t[-1]), "a": a[-1].copy(), "v": v[-1].copy(), "d": d[-1].copy()}
        self.last.update({f"end_{k}": s[-1].copy() for k, s in series.items()})
        return v, d, series

    def _read_at(self, t: np.ndarray, series: dict[str, np.ndarray]) -> None:
        if self.t0 is None:
            raise RuntimeError("values read before the first sample")
        want = np.maximum(self.req, self.t0)
        prev = self.last
        lo = prev["t"] if prev is not None else t[0]
        sel = np.flatnonzero(np.isnan(self.used) & (want >= lo) & (want <= t[-1]))
        if sel.size == 0:
            return
        tt = t if prev is None else np.concatenate([[prev["t"]], t])
        dd = series["d"] if prev is None else np.concatenate([prev["end_d"][None, :], series["d"]])
        at = np.clip(np.searchsorted(tt, want[sel], side="right") - 1, 0, max(tt.size - 2, 0))
        for i, j in zip(sel, at, strict=True):
            self.brackets[int(i)] = (tt[j : j + 2].copy(), dd[j : j + 2].copy())
        for k, s in series.items():
            ss = s if prev is None else np.concatenate([prev[f"end_{k}"][None, :], s])
            out = self.at.setdefault(k, np.full((self.req.size, 3), np.nan))
            for j in range(3):  # 3 columns: not a per-sample loop
                out[sel, j] = np.interp(want[sel], tt, ss[:, j])
        self.used[sel] = want[sel]

    def finish(self) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, np.ndarray]]:
        """(t_used_s, values at the times per series, end values per series); values_at's rule: a
        time after the last sample within tolerance_s takes the last sample, further out NaN."""
        if self.last is None:
            raise RuntimeError("finish() before any sample was added")
        t_end = self.last["t"]
        late = np.isnan(self.used) & (self.req > t_end) & (self.req - t_end <= self.tol)
        ends = {k[4:]: v for k, v in self.last.items() if k.startswith("end_")}
        for k, e in ends.items():
            out = self.at.setdefault(k, np.full((self.req.size, 3), np.nan))
            out[late] = e
        self.used[late] = t_end
        return self.used.copy(), self.at, ends

    def series_at(self, fn: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """(values at the times (m,3), end value (3,)) of the series fn(t, d) after finish(), as the
        extra argument of add would have read them: fn on the two samples around each time (a
        pointwise fn, e.g. DriftModel.apply, gives the same interpolation), at the end on the last."""
        if self.last is None:
            raise RuntimeError("series_at() before any sample was added")
        end = fn(np.array([self.last["t"]]), self.last["d"][None, :])[0]
        out = np.full((self.req.size, 3), np.nan)
        for i, (tb, db) in self.brackets.items():
            s = fn(tb, db)
            for j in range(3):
                out[i, j] = np.interp(self.used[i], tb, s[:, j])
        late = np.isfinite(self.used) & ~np.isin(np.arange(self.req.size), list(self.brackets))
        out[late] = end
        return out, end


class ResidualSums:
    """Everything `evaluate` reports about one residual series r (n,3) m/s^2 fed block by block:
    mean, std, tau, RMS of window means, displacement at times and at the end (module doc).

    drift: a DriftModel applied to d(t) (its series read at the same times); keep_series keeps
    t, r, d (and the drifted d) for plots (the whole-session path)."""

    def __init__(
        self, times_s: Sequence[float], window_s: float, drift=None, keep_series: bool = False
    ) -> None:
        self.n = 0
        self.shift: np.ndarray | None = None
        self.s1 = np.zeros(3)
        self.s2 = np.zeros(3)
        self.tau = AutocorrTime()
        self.windows = WindowCarry(window_s)
        self.win_sq = 0.0
        self.win_n = 0
        self.integ = Integrator(times_s)
        self.drift = drift
        self.t_first = self.t_last = np.nan
        self.keep = keep_series
        self.series: dict[str, list[np.ndarray]] = {"t": [], "r": [], "v": [], "d": [], "dd": []}

    def add(self, t: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fold one block in; returns its (v, d) (m/s, m) for a caller writing them out."""
        if t.shape[0] == 0:
            z = np.zeros((0, 3))
            return z, z
        if self.shift is None:
            self.shift = r.mean(axis=0)
            self.t_first = float(t[0])
        y = r - self.shift
        self.n += t.shape[0]
        self.s1 += y.sum(axis=0)
        self.s2 += (y * y).sum(axis=0)
        self.tau.add(r)
        self._windows(self.windows.push(t, r))
        extra = None
        if self.drift is not None:
            dm = self.drift
            extra = lambda tb, d: {"dd": dm.apply(tb, d)}  # noqa: E731
        v, d, series = self.integ.add(t, r, extra)
        self.t_last = float(t[-1])
        if self.keep:
            for k, s in (("t", t), ("r", r), ("v", v), ("d", d), ("dd", series.get("dd"))):
                if s is not None:
                    self.series[k].append(s)
        return v, d

    def _windows(self, out) -> None:
        if out is None:
            return
        _t, (r,), starts = out
        sums = np.add.reduceat(r, starts, axis=0)
        cnt = np.diff(np.append(starts, r.shape[0]))[:, None]
        self.win_sq += float(np.sum((sums / cnt) ** 2))
        self.win_n += sums.size

    def finish(self) -> dict:
        """Statistics of everything added (keys as Evaluation's fields)."""
        self._windows(self.windows.flush())
        if self.shift is None:
            raise RuntimeError("finish() before any sample was added")
        n = self.n
        m_c = self.s1 / n
        var = np.maximum(self.s2 - n * m_c**2, 0.0) / max(n - 1, 1)
        used, at, ends = self.integ.finish()
        out = {
            "n": n,
            "mean": m_c + self.shift,
            "std": np.sqrt(var),
            "tau": self.tau.tau(),
            "rms": float(np.sqrt(self.win_sq / self.win_n)),
            "t_used": used,
            "disp_at": at["d"],
            "disp_end": ends["d"],
            "disp_drift_at": at.get("dd"),
            "disp_drift_end": ends.get("dd"),
            "t_first": self.t_first,
            "t_last": self.t_last,
        }
        if self.keep:  # one block (a session in memory) is handed over as it is (t: the session's own array)
            out["series"] = {
                k: v[0] if len(v) == 1 else np.concatenate(v) for k, v in self.series.items() if v
            }
            self.series = {k: [] for k in self.series}
        return out
