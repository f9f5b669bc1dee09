"""The doctor's checks fed block by block (accellog.flows.doctor): memory flat in the session's length.

``Tally``: the distinct values of a series and their counts; its median and percentiles are numpy's
(np.median; np.percentile, linear) of the whole series, exactly while the distinct values number
<= ``cap`` (always for stamps on a grid, and for any series of <= cap values); beyond, every value is
rounded to fewer mantissa bits (relative error <= 2^-(bits+1)) until they fit. No cap: exact.

``Thinned``: every m-th sample (t, accel, gyro, temperature; m = 1, 2, 4, ... the least that keeps
<= cap samples), for the checks that need the whole series at once: still intervals (a centred
moving variance, a percentile threshold), the units' medians and the clip gate's median and MAD.
m = 1 (the series itself) while the session has <= cap samples.

``Where``: a count and the sensor times (s) of the first ``WHERE_N`` flagged samples.
``Extreme``: the runs of >= 3 consecutive samples at a series' maximum (or minimum) so far.
"""

from __future__ import annotations

import numpy as np

from accellog.core.session import Session, SessionMeta
from accellog.core.timeseries import runs
from accellog.store.stream import ImuBlock

TALLY_CAP = 1 << 18
THIN_CAP = 1 << 18
WHERE_N = 50


def _unique_weighted(v: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sorted distinct values of v and the summed weights c of each."""
    order = np.argsort(v, kind="stable")
    v, c = v[order], c[order]
    if v.size == 0:
        return v, c
    start = np.flatnonzero(np.concatenate([[True], v[1:] != v[:-1]]))
    return v[start], np.add.reduceat(c, start)


def _round_bits(x: np.ndarray, bits: int) -> np.ndarray:
    """x with its mantissa rounded to `bits` bits."""
    m, e = np.frexp(x)
    return np.ldexp(np.round(m * 2.0**bits) / 2.0**bits, e)


class Tally:
    """Distinct values and counts of every value added (module doc); NaNs are counted apart."""

    def __init__(self, cap: int | None = TALLY_CAP) -> None:
        self.cap, self.bits, self.nan = cap, 52, 0
        self.values, self.counts = np.empty(0), np.empty(0, np.int64)
        self._parts: list[tuple[np.ndarray, np.ndarray]] = []
        self._pending = 0
        self._cum: np.ndarray | None = None

    @classmethod
    def of(cls, values: np.ndarray, counts: np.ndarray) -> Tally:
        """The tally of values repeated counts times (exact)."""
        t = cls(cap=None)
        t.values, t.counts = _unique_weighted(np.asarray(values, float), np.asarray(counts, np.int64))
        return t

    @property
    def exact(self) -> bool:
        return self.bits == 52

    def add(self, x: np.ndarray) -> None:
        x = np.asarray(x, float)
        nan = np.isnan(x)
        if nan.any():
            self.nan += int(nan.sum())
            x = x[~nan]
        if not self.exact:
            x = _round_bits(x, self.bits)
        v, c = np.unique(x, return_counts=True)
        self._parts.append((v, c.astype(np.int64)))
        self._pending += v.size
        self._cum = None
        if self.cap is not None and self._pending > self.cap:
            self._merge()

    def _merge(self) -> None:
        if self._parts:
            v = np.concatenate([self.values] + [p[0] for p in self._parts])
            c = np.concatenate([self.counts] + [p[1] for p in self._parts])
            self.values, self.counts = _unique_weighted(v, c)
            self._parts, self._pending = [], 0
        while self.cap is not None and self.values.size > self.cap:
            self.bits -= 4
            self.values, self.counts = _unique_weighted(_round_bits(self.values, self.bits), self.counts)
        self._pending = self.values.size

    def done(self) -> Tally:
        self._cumulative()
        return self

    def _cumulative(self) -> np.ndarray:
        """Cumulative counts of the merged values (made once after the last add)."""
        self._merge()
        if self._cum is None:
            self._cum = np.cumsum(self.counts)
        return self._cum

    @property
    def n(self) -> int:
        """Values added (NaNs included)."""
        cum = self._cumulative()
        return int(cum[-1]) + self.nan if cum.size else self.nan

    def _at(self, k: int) -> float:
        """The k-th smallest value (0-based) of the non-NaN values."""
        return float(self.values[np.searchsorted(self._cumulative(), k, side="right")])

    def median(self) -> float:
        """np.median of the values."""
        n = self.n
        if self.nan or not n:
            return float("nan")
        if n % 2:
            return self._at(n // 2)
        return float((np.float64(self._at(n // 2 - 1)) + np.float64(self._at(n // 2))) / 2.0)

    def percentile(self, p: float) -> float:
        """np.percentile(values, p) (method 'linear': the order statistics at floor and ceil of
        (n - 1) p / 100, interpolated as numpy's _lerp)."""
        n = self.n
        if self.nan or not n:
            return float("nan")
        vi = (n - 1) * np.true_divide(p, 100)
        if vi >= n - 1:
            return self._at(n - 1)
        lo = int(np.floor(vi))
        g = float(vi - np.floor(vi))
        a, b = np.float64(self._at(lo)), np.float64(self._at(lo + 1))
        d = b - a
        return float(b - d * (1 - g) if g >= 0.5 else a + d * g)

    def max(self) -> float:
        self.done()
        return float("nan") if self.nan or not self.values.size else float(self.values[-1])

    def where(self, mask_of) -> Tally:
        """The tally of the values v with mask_of(v) true."""
        self.done()
        keep = mask_of(self.values)
        return Tally.of(self.values[keep], self.counts[keep])

    def count(self, mask_of) -> int:
        self.done()
        return int(self.counts[mask_of(self.values)].sum())


class Where:
    """How many samples were flagged, and the times of the first WHERE_N."""

    def __init__(self) -> None:
        self.count = 0
        self.t_s: list[float] = []

    def add(self, t: np.ndarray, mask: np.ndarray) -> None:
        idx = np.flatnonzero(mask)
        self.count += idx.size
        if len(self.t_s) < WHERE_N:
            self.t_s += [float(x) for x in t[idx[: WHERE_N - len(self.t_s)]]]


class Thinned:
    """Every m-th sample of a session (module doc); session() makes a Session of them."""

    NAMES = ("t_s", "accel_g", "gyro_dps", "temp_degC")

    def __init__(self, cap: int | None = THIN_CAP) -> None:
        self.cap, self.m, self.n, self.kept = cap, 1, 0, 0
        self.parts: dict[str, list[np.ndarray]] = {k: [] for k in self.NAMES}

    def add(self, b: ImuBlock) -> None:
        sl = slice((-self.n) % self.m, None, self.m)
        for k in self.NAMES:
            a = getattr(b, k)
            if a is not None:  # a copy: a view would keep the whole block
                self.parts[k].append(a[sl].copy() if self.m > 1 else a)
        self.n += b.n
        self.kept += b.t_s[sl].shape[0]
        while self.cap is not None and self.kept > self.cap:
            for k, p in self.parts.items():
                if p:
                    self.parts[k] = [np.concatenate(p)[::2].copy()]
            self.m *= 2
            self.kept = self.parts["t_s"][0].shape[0]

    def session(self, meta: SessionMeta, poses: list, events: list, path: str | None) -> Session:
        a = {k: np.concatenate(p) if p else None for k, p in self.parts.items()}
        t = a["t_s"] if a["t_s"] is not None else np.empty(0)
        acc = a["accel_g"] if a["accel_g"] is not None else np.empty((0, 3))
        return Session(meta=meta, t_s=t, sample_index=np.arange(t.shape[0], dtype=np.int64) * self.m,
                       accel_g=acc, gyro_dps=a["gyro_dps"], temp_degC=a["temp_degC"],
                       poses=list(poses), events=list(events), path=path)  # fmt: skip


class Extreme:
    """Runs (>= 3 samples) at the maximum (sign +1) or minimum (-1) of a series fed block by block:
    [start, stop) sample indexes, and the times of the first WHERE_N samples in them."""

    def __init__(self, sign: int) -> None:
        self.sign = sign
        self.value: float | None = None  # the extreme so far
        self.runs: list[list[int]] = []  # [start, stop) of runs at value; the last may be open
        self.t_s: list[list[float]] = []  # the times of each run's first samples (WHERE_N in all)
        self.open = False  # the last run reaches the end of the last block

    def add(self, v: np.ndarray, t: np.ndarray, n0: int) -> None:
        if not v.size or (self.value is not None and np.isnan(self.value)):
            return
        top = float(v.max() if self.sign > 0 else v.min())
        if self.value is None or np.isnan(top) or (top - self.value) * self.sign > 0:
            self.value, self.runs, self.t_s, self.open = top, [], [], False
            if np.isnan(top):
                return
        r = runs(v == self.value)
        if self.open and (not r.size or r[0, 0] > 0):
            self._close()
        for k, (a, b) in enumerate(r):
            if k == 0 and a == 0 and self.open:
                self.runs[-1][1] = n0 + b
            else:
                self.runs.append([n0 + a, n0 + b])
                self.t_s.append([])
            room = WHERE_N - sum(len(x) for x in self.t_s)
            have = self.runs[-1][1] - self.runs[-1][0] - (b - a)  # samples of this run before this block
            if room > 0 and have <= len(self.t_s[-1]):
                self.t_s[-1] += [float(x) for x in t[a : min(b, a + room)]]
            self.open = b == v.size
            if not self.open:
                self._close()

    def _close(self) -> None:
        self.open = False
        if self.runs and self.runs[-1][1] - self.runs[-1][0] < 3:
            self.runs.pop()
            self.t_s.pop()


def flat_tops(extremes: list[Extreme], times_of) -> tuple[int, list[float]]:
    """(samples in any of the extremes' runs, times of the first WHERE_N of them); times_of(e) is
    the (index, time) pairs the extreme kept."""
    spans = sorted(tuple(r) for e in extremes for r in e.runs if r[1] - r[0] >= 3)
    total, end = 0, -1
    for a, b in spans:
        if b > end:
            total += b - max(a, end)
            end = b
    first = sorted({i: t for e in extremes for i, t in times_of(e)}.items())[:WHERE_N]
    return total, [t for _, t in first]


def kept_times(e: Extreme) -> list[tuple[int, float]]:
    """(sample index, time) of the samples whose time e kept (its runs' first samples)."""
    return [
        (r[0] + j, t)
        for r, ts in zip(e.runs, e.t_s, strict=True)
        if r[1] - r[0] >= 3
        for j, t in enumerate(ts)
    ]


class Scan:
    """One pass over a session's blocks: the interval tally, duplicated and decreasing stamps,
    saturated counts, the extremes of every axis, temperature range and the thinned series. caps None
    (a session in memory): every statistic exact."""

    SENSORS = (("accel", "accel_counts", "accel_g"), ("gyro", "gyro_counts", "gyro_dps"))

    def __init__(self, *, bounded: bool, keep_times: bool = False) -> None:
        self.dt = Tally(TALLY_CAP if bounded else None)
        self.thin = Thinned(THIN_CAP if bounded else None)
        self.dup, self.back = Where(), Where()
        self.sat = {name: Where() for name, _, _ in self.SENSORS}
        self.counted = {name: False for name, _, _ in self.SENSORS}
        self.ext = {name: [Extreme(s) for _ in range(3) for s in (1, -1)] for name, _, _ in self.SENSORS}
        self.has = {name: False for name, _, _ in self.SENSORS}
        self.n = 0
        self.t0: float | None = None  # first and last stamp (s)
        self.last: float | None = None
        self.dt_max = -np.inf
        self.temp: tuple[float, float] | None = None
        self.times: list[np.ndarray] | None = [] if keep_times else None

    def add(self, b: ImuBlock) -> None:
        t = b.t_s
        if not b.n:
            return
        tt = t if self.last is None else np.concatenate([[self.last], t])
        dt = np.diff(tt)
        self.dt.add(dt)
        if dt.size:  # exact whatever the tally rounds (NaN stays NaN, as np.max)
            self.dt_max = np.maximum(self.dt_max, dt.max())
        self.dup.add(tt[1:], dt == 0)
        self.back.add(tt[1:], dt < 0)
        for name, counts_key, values_key in self.SENSORS:
            counts, values = getattr(b, counts_key), getattr(b, values_key)
            if values is None:
                continue
            self.has[name] = True
            if counts is not None:
                self.counted[name] = True
                self.sat[name].add(t, np.any((counts >= 32767) | (counts <= -32768), axis=1))
            else:
                for k, e in enumerate(self.ext[name]):
                    e.add(values[:, k // 2], t, self.n)
        if b.temp_degC is not None:
            lo, hi = np.min(b.temp_degC), np.max(b.temp_degC)
            self.temp = (
                (lo, hi)
                if self.temp is None
                else (np.minimum(self.temp[0], lo), np.maximum(self.temp[1], hi))
            )
        self.thin.add(b)
        if self.times is not None:
            self.times.append(t)
        self.t0 = t[0] if self.t0 is None else self.t0
        self.last = t[-1]
        self.n += b.n


class Gaps:
    """The second pass of the timing check, once the median interval med (s) is known: gaps
    (dt > gap med: count, samples missing, longest) and bursts (0 < dt < burst med), located."""

    def __init__(self, med: float, gap: float, burst: float) -> None:
        self.med, self.gap_s, self.burst_s = med, gap * med, burst * med
        self.gaps, self.bursts = Where(), Where()
        self.missing, self.longest_s = 0, -np.inf
        self.last: float | None = None  # the previous block's last stamp (s)

    def add(self, t: np.ndarray) -> None:
        if not t.size:
            return
        tt = t if self.last is None else np.concatenate([[self.last], t])
        dt = np.diff(tt)
        g = dt > self.gap_s
        self.gaps.add(tt[:-1], g)
        if g.any():
            self.missing += int(np.sum(np.round(dt[g] / self.med) - 1))
            self.longest_s = max(self.longest_s, float(dt[g].max()))
        self.bursts.add(tt[1:], (dt > 0) & (dt < self.burst_s))
        self.last = t[-1]
