"""One labelled hold: its checks, its observation rows and its statistics (accelerations in g).

The stage 'segment' (``stream_segment.segment_blocks``) hands every trimmed hold's samples here as
``HoldSamples`` (kept as they came, or beyond SPILL_ROWS in an unnamed temporary file) and reduces
them in two passes of CHUNK_ROWS samples, so memory does not grow with the hold's length:
``first_pass`` (count, times, mean, non-finite readings) for ``check_hold`` (unit up vector, enough
samples, finite readings) and ``units_error`` (|mean| near 1 g), then ``reduce_hold``: the windows of
about window_s (one observation each), the motion check's windows, the autocorrelation time and the
``PoseStats``. A window's observation is

    meas_g = window mean (g),   sigma_g = std_window * sqrt(tau_hold / n_window)   (g)

where tau_hold is the hold's integrated autocorrelation time (samples, ``hold_noise``), floored
at the quantum / sqrt(12 n). Several windows per hold keep slow effects (temperature, warm-up,
time drift) visible to the fit.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from accellog.calibrate.observe.hold_noise import (
    BLOCK,
    BLOCK_GROUP,
    AutocorrTime,
    integrated_autocorr_time,
    sem_of,
)
from accellog.calibrate.observe.window_spill import WindowSpill
from accellog.core.errors import InputError
from accellog.core.session import PoseLabel, Session, SessionMeta

UNIT_NORM_RANGE_G = (0.5, 2.0)
"""A reading at rest must have |a| in this range (g); outside it the units are wrong."""
MIN_WINDOW_SAMPLES = 10
"""A window must hold this many samples (its mean and std mean nothing with fewer)."""
CHUNK_ROWS = BLOCK * BLOCK_GROUP
"""Samples of a hold reduced at a time (131072: 5 MB of time, acceleration and temperature), a
multiple of the autocorrelation's block."""
SPILL_ROWS = 1 << 18
"""A hold read from a file keeps up to this many samples in memory (4.4 min at 1 kHz, 10 MB); a
longer one goes on in an unnamed temporary file (in the page cache, not the process). `evaluate`
of a 4 h 24-pose session (10 min holds) peaked at 227 MB with its holds in memory, 178 MB spilled
(1 h, 150 s holds, not spilled: 153 MB)."""


@dataclass
class PoseStats:
    """Statistics of one labelled hold after trimming (accelerations in g)."""

    name: str
    hold_index: int
    up_sensor: np.ndarray  # (3,) nominal up vector
    start_s: float  # first used sample time (s)
    end_s: float  # last used sample time (s)
    n: int  # samples used
    mean_g: np.ndarray  # (3,)
    std_g: np.ndarray  # (3,) sample standard deviation
    sem_g: np.ndarray  # (3,) autocorrelation-aware standard error of the mean
    tau_samples: np.ndarray  # (3,) integrated autocorrelation time
    temp_degC: float | None = None  # mean die temperature
    dtemp_degC_per_s: float | None = None  # temperature slope over the hold

    @property
    def n_eff(self) -> np.ndarray:
        """Effective sample size n / tau per axis."""
        return self.n / self.tau_samples

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "hold_index": self.hold_index,
            "up_sensor": self.up_sensor.tolist(),
            "start_s": self.start_s,
            "end_s": self.end_s,
            "n": self.n,
            "mean_g": self.mean_g.tolist(),
            "std_g": self.std_g.tolist(),
            "sem_g": self.sem_g.tolist(),
            "tau_samples": self.tau_samples.tolist(),
            "n_eff": self.n_eff.tolist(),
            "temp_degC": self.temp_degC,
            "dtemp_degC_per_s": self.dtemp_degC_per_s,
        }


def session_where(session: Session) -> str:
    return session.path or f"session ({session.meta.source})"


def quantum_g(session: Session) -> float:
    return meta_quantum_g(session.meta)


def meta_quantum_g(meta: SessionMeta) -> float:
    """One LSB (g) of the session's accelerometer; 0 when unknown."""
    lsb = meta.accel_lsb_per_g
    return 1.0 / lsb if lsb else 0.0


def check_window(window_s: float, rate_hz: float, where: str | None = None) -> None:
    """InputError unless window_s (s) holds >= MIN_WINDOW_SAMPLES samples at rate_hz (Hz; 0 or
    unknown: the chip's highest rate, 4 kHz)."""
    rate = rate_hz if np.isfinite(rate_hz) and rate_hz > 0 else 4000.0
    if not window_s * rate >= MIN_WINDOW_SAMPLES:
        raise InputError(
            f"window_s = {window_s:g} s holds {window_s * rate:.3g} samples at {rate:g} Hz; a window "
            f"needs >= {MIN_WINDOW_SAMPLES} (--window-s >= {MIN_WINDOW_SAMPLES / rate:g} s)",
            where=where,
        )


def checked_labels(poses: Sequence[PoseLabel], where: str, events: Sequence = ()) -> list[PoseLabel]:
    """The labels in time order after the label-level checks (none, twice, empty, overlapping);
    events: the session's (a 'recovered' one says that missing labels went with a truncated end)."""
    if not poses:
        cut = next((f"the file is truncated: they went with its end ({e.detail})" for e in events
                    if e.kind == "recovered"), "record it with a pose protocol")  # fmt: skip
        raise InputError(
            f"session has no pose labels: {cut}; or use the orientation-free fit (static intervals are then "
            "detected automatically)",
            where=where,
        )
    labels = sorted(poses, key=lambda p: p.start_s)
    seen: dict[tuple[str, int], PoseLabel] = {}
    for p in labels:
        key = (p.name, p.hold_index)
        if key in seen:
            q = seen[key]
            raise InputError(
                f"pose {p.name!r} (hold {p.hold_index}) is labelled twice: {q.start_s:.2f}-{q.end_s:.2f} s "
                f"and {p.start_s:.2f}-{p.end_s:.2f} s",
                where=where,
            )
        seen[key] = p
        if not p.end_s > p.start_s:
            raise InputError(f"pose {p.name!r} has end {p.end_s} s <= start {p.start_s} s", where=where)
    for a, b in itertools.pairwise(labels):
        if b.start_s < a.end_s - 1e-9:
            raise InputError(
                f"poses {a.name!r} ({a.start_s:.2f}-{a.end_s:.2f} s) and {b.name!r} "
                f"({b.start_s:.2f}-{b.end_s:.2f} s) overlap",
                where=where,
            )
    return labels


class HoldSamples:
    """One trimmed hold's samples (t s, accel g, temperature degC or None) in time order as they
    pass: kept as given (views of the blocks), or once more than spill_rows (None: never) in an
    unnamed temporary file. chunks() yields them again, in order, CHUNK_ROWS at a time."""

    def __init__(self, spill_rows: int | None = None) -> None:
        self.parts: list[tuple] = []
        self.n = 0
        self.spill_rows = spill_rows
        self.spill: WindowSpill | None = None
        self.has_temp = False

    def add(self, t: np.ndarray, acc: np.ndarray, temp: np.ndarray | None) -> None:
        if t.shape[0] == 0:
            return
        if self.n == 0:
            self.has_temp = temp is not None
        self.n += t.shape[0]
        if self.spill is not None:
            self._write(t, acc, temp)
            return
        self.parts.append((t, acc, temp))
        if self.spill_rows is not None and self.n > self.spill_rows:
            self.spill = WindowSpill(5 if self.has_temp else 4)
            for part in self.parts:
                self._write(*part)
            self.parts = []

    def _write(self, t: np.ndarray, acc: np.ndarray, temp: np.ndarray | None) -> None:
        if self.spill is not None:
            cols = [t, acc]
            if self.has_temp:
                assert temp is not None  # has_temp: every part carries one
                cols.append(temp)
            self.spill.append(np.column_stack(cols))

    def chunks(self, rows: int = CHUNK_ROWS) -> Iterator[tuple]:
        """(t, acc, temp or None) of rows samples at a time (the last: the rest), in order."""
        if self.spill is not None:
            for w in self.spill.pieces(rows):
                yield w[:, 0], w[:, 1:4], w[:, 4] if self.has_temp else None
            return
        buf: list[tuple] = []
        k = 0
        for part in self.parts:
            i, m = 0, part[0].shape[0]
            while i < m:
                take = min(rows - k, m - i)
                buf.append(tuple(None if x is None else x[i : i + take] for x in part))
                k, i = k + take, i + take
                if k == rows:
                    yield _joined(buf)
                    buf, k = [], 0
        if buf:
            yield _joined(buf)

    def close(self) -> None:
        if self.spill is not None:
            self.spill.close()


def _joined(pieces: list[tuple]) -> tuple:
    """(t, acc, temp or None) of consecutive pieces (the piece itself when there is one)."""
    if len(pieces) == 1:
        return pieces[0]
    return tuple(None if pieces[0][i] is None else np.concatenate([p[i] for p in pieces]) for i in range(3))


@dataclass
class FirstPass:
    """What one pass over a hold's samples gives before any window is cut (times s, accel g)."""

    n: int
    t_first: float
    t_last: float
    mean: np.ndarray  # (3,)
    t_mean: float
    temp_mean: float | None
    n_bad: int  # samples with a non-finite reading
    t_bad: float  # time of the first


def first_pass(samples: HoldSamples) -> FirstPass:
    """Count, first and last time, means and non-finite readings of a hold (one chunk: the bits of
    acc.mean(axis=0), t.mean() and temp.mean() of the whole hold)."""
    n, s, st, stemp, n_bad = 0, np.zeros(3), 0.0, 0.0, 0
    t0 = t1 = t_bad = float("nan")
    for t, acc, temp in samples.chunks():
        if n == 0:
            t0 = float(t[0])
        t1 = float(t[-1])
        if not np.isfinite(acc).all():  # one flat pass; the rows only when one is bad
            bad = ~np.isfinite(acc).all(axis=1)
            t_bad = float(t[int(np.argmax(bad))]) if n_bad == 0 else t_bad
            n_bad += int(bad.sum())
        n += t.shape[0]
        s = s + acc.sum(axis=0)
        st += float(t.sum())
        if temp is not None:
            stemp += float(temp.sum())
    d = max(n, 1)
    return FirstPass(n, t0, t1, s / d, st / d, stemp / d if samples.has_temp else None, n_bad, t_bad)


def check_hold(p: PoseLabel, first: FirstPass, trim_s: float, min_samples: int, where: str) -> None:
    """InputError for a hold whose label's up vector is not a unit 3-vector, that has fewer than
    min_samples (at least 1) samples after trimming trim_s (s), or a non-finite reading."""
    up = np.asarray(p.up_sensor, float)
    if up.shape != (3,) or not np.isfinite(up).all() or abs(np.linalg.norm(up) - 1.0) > 1e-3:
        raise InputError(f"pose {p.name!r}: up vector {p.up_sensor} is not a unit 3-vector", where=where)
    if first.n < max(min_samples, 1):
        raise InputError(
            f"pose {p.name!r} ({p.start_s:.2f}-{p.end_s:.2f} s) has {first.n} samples after trimming "
            f"{trim_s} s at each end (need >= {min_samples}): hold longer or lower --trim",
            where=where,
        )
    if first.n_bad:
        raise InputError(
            f"pose {p.name!r}: accel is NaN/inf at t = {first.t_bad:.3f} s ({first.n_bad} bad samples)",
            where=where,
        )


def units_error(p: PoseLabel, mean: np.ndarray, where: str) -> InputError | None:
    """The refusal of a hold whose mean reading (g) is far from 1 g (wrong units), else None."""
    lo, hi = UNIT_NORM_RANGE_G
    norm = float(np.linalg.norm(mean))
    if lo <= norm <= hi:
        return None
    hint = " (are raw counts declared as g? check accel_lsb_per_g)" if norm > hi else ""
    return InputError(
        f"pose {p.name!r}: |accel| at rest is {norm:.4g} g, expected about 1 g{hint}", where=where
    )


def window_stats(x: np.ndarray, starts: np.ndarray, ref=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mean, std (ddof=1), n) of x (n,k) over windows at indices `starts` (sorted); ref: x's mean, if known."""
    ref = x.mean(axis=0) if ref is None else ref
    return centred_window_stats(x - ref, starts, ref)


def centred_window_stats(
    xc: np.ndarray, starts: np.ndarray, ref
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """window_stats of x from xc = x - ref (made once by a caller that needs it again)."""
    n = np.diff(np.append(starts, xc.shape[0]))
    s1 = np.add.reduceat(xc, starts, axis=0)
    s2 = np.add.reduceat(xc * xc, starts, axis=0)
    return _moments(s1, s2, n, ref)


def _moments(s1: np.ndarray, s2: np.ndarray, n: np.ndarray, ref) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mean, std (ddof=1), n) of windows from their sums s1 = sum(x - ref), s2 = sum((x - ref)^2)."""
    mean_c = s1 / n[:, None]
    var = np.maximum(s2 - n[:, None] * mean_c**2, 0.0) / np.maximum(n - 1, 1)[:, None]
    return mean_c + ref, np.sqrt(var), n


def window_edges(t0: float, t1: float, window_s: float) -> np.ndarray:
    """Starts (s) of the motion check's windows of window_s over [t0, t1]: np.arange(t0, t1, window_s)."""
    edges = np.arange(t0, t1, window_s)
    return edges if edges.size else np.array([t0])


class WindowSums:
    """Sums of a hold's windows starting at edges (s, rising; edges[0] <= the first sample) over
    its chunks: a sample at t belongs to the last edge <= t, as np.searchsorted(t, edges) cuts the
    whole hold; windows no sample falls in are dropped at the end."""

    def __init__(self, edges: np.ndarray, t0: float, temp: bool) -> None:
        k = len(edges)
        self.edges, self.t0 = edges, t0
        self.s1, self.s2 = np.zeros((k, 3)), np.zeros((k, 3))
        self.n = np.zeros(k, np.int64)
        self.tsum = np.zeros(k)
        self.temp = np.zeros(k) if temp else None
        self.first, self.last = np.full(k, np.nan), np.full(k, np.nan)

    def add(self, t: np.ndarray, xc: np.ndarray, xx: np.ndarray, temp: np.ndarray | None) -> None:
        """One chunk: times t, accel - hold mean xc and its square xx, temperature."""
        m = t.shape[0]
        w0 = int(np.searchsorted(self.edges, t[0], side="right")) - 1  # the window of the first sample
        pos = np.searchsorted(t, self.edges[w0 + 1 :])  # first sample >= each later edge (>= 1)
        ids = np.arange(w0 + 1, w0 + 1 + pos.size)[pos < m]
        pos = pos[pos < m]
        last = np.ones(pos.size, bool)  # of edges on one sample, the last holds it
        last[:-1] = pos[1:] != pos[:-1]
        starts = np.concatenate([[0], pos[last]])
        ids = np.concatenate([[w0], ids[last]])
        cnt = np.diff(np.append(starts, m))
        self.s1[ids] += np.add.reduceat(xc, starts, axis=0)
        self.s2[ids] += np.add.reduceat(xx, starts, axis=0)
        self.n[ids] += cnt
        self.tsum[ids] += np.add.reduceat(t - self.t0, starts)
        if self.temp is not None and temp is not None:
            self.temp[ids] += np.add.reduceat(temp, starts)
        self.first[ids] = np.where(np.isnan(self.first[ids]), t[starts], self.first[ids])
        self.last[ids] = t[starts + cnt - 1]

    def stats(
        self, ref: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """(first time, last time, mean, std (ddof=1), n, mean time, mean temperature or None) of
        the windows holding samples."""
        k = self.n > 0
        n = self.n[k]
        mean, std, n = _moments(self.s1[k], self.s2[k], n, ref)
        temp = None if self.temp is None else self.temp[k] / n
        return self.first[k], self.last[k], mean, std, n, self.tsum[k] / n + self.t0, temp


@dataclass
class HoldReduction:
    """reduce_hold's result for one trimmed hold (accelerations g, times s)."""

    tau: np.ndarray  # (3,) integrated autocorrelation time (samples, hold_noise)
    rows: dict[str, np.ndarray] | None  # ObsTable columns (pose_id apart) of its windows
    windows: tuple | None  # the motion check's windows: (start s, end s, mean, std, n)
    stats: PoseStats | None


def reduce_hold(
    p: PoseLabel, samples: HoldSamples, first: FirstPass, *, window_s: float | None, quantum: float,
    motion_window_s: float | None = 0.5, stats: bool = False,
) -> HoldReduction:  # fmt: skip
    """The second pass over a checked hold (first: its first_pass): the observation rows of the
    windows of about window_s (None: none), the motion check's windows of motion_window_s (None:
    none), the hold's PoseStats when stats. Rows: meas_g = window mean, sigma_g = std_window
    sqrt(tau_hold / n_window) (floored at quantum / sqrt(12 n)), t_s = mean sample time of the
    window, t_in_pose_s = t_s - label start, temp_degC = window mean, dtemp_degC_per_s = slope of
    the window means within the hold (the hold's least-squares slope for a single-window hold),
    q = the label's nominal orientation (NaN if unknown)."""
    t0, t1, mean, n_all = first.t_first, first.t_last, first.mean, first.n
    rows = win = None
    if window_s is not None:
        nwin = max(1, int(np.floor((t1 - t0) / window_s + 1e-9)))
        rows = WindowSums(t0 + (t1 - t0) * np.arange(nwin) / nwin, t0, samples.has_temp)
    if motion_window_s is not None:
        win = WindowSums(window_edges(t0, t1, motion_window_s), t0, False)
    long = n_all > 2 * BLOCK
    tau_acc = AutocorrTime() if long else None
    s2, tt, tT = np.zeros(3), 0.0, 0.0  # sum xc^2; sums of (t - t_mean)^2 and (t - t_mean)(T - T_mean)
    tau = None
    for t, acc, temp in samples.chunks():
        xc = acc - mean  # once, for the windows and the autocorrelation
        xx = xc * xc
        s2 = s2 + xx.sum(axis=0)
        for w in (rows, win):
            if w is not None:
                w.add(t, xc, xx, temp)
        if tau_acc is not None:
            tau_acc.add(xc)
        else:  # one chunk holds it all
            tau = np.asarray(integrated_autocorr_time(xc, centred=True))
        if temp is not None and first.temp_mean is not None:
            tc = t - first.t_mean
            tt += float(tc @ tc)
            tT += float(tc @ (temp - first.temp_mean))
    if tau_acc is not None:
        tau = tau_acc.tau()
    if tau is None:
        raise RuntimeError("reduce_hold of an empty hold")
    slope = tT / tt if tt > 0 else 0.0
    cols = None if rows is None else _rows(p, rows, mean, tau, quantum, slope)
    ps = None
    if stats:
        std = np.sqrt(s2 / max(n_all - 1, 1))
        ps = PoseStats(
            name=p.name, hold_index=p.hold_index, up_sensor=np.asarray(p.up_sensor, float), start_s=t0,
            end_s=t1, n=n_all, mean_g=mean, std_g=std, sem_g=sem_of(std, tau, n_all, quantum),
            tau_samples=tau, temp_degC=first.temp_mean, dtemp_degC_per_s=slope if first.temp_mean is not None else None,
        )  # fmt: skip
    return HoldReduction(tau, cols, None if win is None else win.stats(mean)[:5], ps)


def _rows(p: PoseLabel, sums: WindowSums, mean, tau, quantum: float, slope: float) -> dict[str, np.ndarray]:
    """reduce_hold's ObsTable columns of one hold from its window sums."""
    _t0, _t1, wmean, std, n, tmid, tw = sums.stats(mean)
    sigma = np.maximum(std * np.sqrt(tau[None, :] / n[:, None]), quantum / np.sqrt(12.0 * n[:, None]))
    k = len(n)
    q = np.asarray(p.q_sensor_to_world, float) if p.q_sensor_to_world is not None else np.full(4, np.nan)
    cols = {
        "meas_g": wmean,
        "sigma_g": sigma,
        "up_sensor": np.tile(np.asarray(p.up_sensor, float), (k, 1)),
        "t_s": tmid,
        "t_in_pose_s": tmid - p.start_s,
        "n_samples": n,
        "std_g": std,
        "q_sensor_to_world": np.tile(q, (k, 1)),
    }
    if tw is not None:
        cols["temp_degC"] = tw
        cols["dtemp_degC_per_s"] = np.gradient(tw, tmid) if k >= 2 else np.array([slope])
    return cols
