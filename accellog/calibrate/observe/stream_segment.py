"""Stage 'segment' on a file, chunk by chunk: the observation table of ``segment.observations``
without loading the session (memory bounded by the longest hold plus one chunk group).

The pose labels are read first (``store.stream.read_labels``); the samples then stream past
(``store.stream.iter_imu``) and each trimmed hold's samples are gathered until the hold ends, cut
into windows and reduced to their rows by ``segment.observations`` on that hold alone, then
dropped. The rows are exactly those of ``observations(read_session(path), ...)``: the same
per-hold code runs on the same samples; the session-wide checks (labels, motion against the
median window noise of all holds) run on the per-hold summaries. Window statistics (means,
standard deviations, autocorrelation time) are sufficient for the fit, the diagnosis and the
cross-validation, which all take the ObsTable.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from accellog.calibrate.observe.heap import trim_heap
from accellog.calibrate.observe.segment import (
    PoseStats,
    check_window,
    checked_labels,
    mean_shift,
    moving_verdict,
    observations,
    pose_stats,
    static_windows,
)
from accellog.calibrate.observe.window_spill import WindowSpill, median
from accellog.core.errors import InputError
from accellog.core.session import ObsTable, PoseLabel, Session, SessionMeta
from accellog.store.stream import iter_imu, read_labels


def stream_observations(
    path: str | Path,
    window_s: float = 2.0,
    trim_s: float = 0.5,
    *,
    min_samples: int = 20,
    check_units: bool = True,
    check_moving: bool = True,
    stats_out: list[PoseStats] | None = None,
    labels: tuple[SessionMeta, list[PoseLabel], list] | None = None,
    on_block=None,
) -> ObsTable:
    """observations(read_session(path), window_s, trim_s, ...) in bounded memory (module doc);
    stats_out (a list), when given, receives pose_stats(read_session(path), trim_s, ...) as well;
    labels: read_labels(path) when the caller has it already; on_block(block), when given, is
    called with every block of the pass (e.g. feeding a TimestampCheck)."""
    where = str(path)
    check_window(window_s, 0.0, where)  # before reading: at most the chip's highest rate
    meta, poses, _events = labels if labels is not None else read_labels(path)
    check_window(window_s, meta.sample_rate_hz, where)
    labels = checked_labels(poses, where)
    gather = _HoldGatherer(labels, trim_s)
    rows = _Rows(sum(_most_windows(p, trim_s, window_s) for p in labels))  # the observation rows
    wins = _HoldWindows() if check_moving else None
    names: list[str] = []

    def reduce(p: PoseLabel, parts: list[tuple]) -> None:
        mini = _hold_session(meta, p, parts, where)
        if mini.n < min_samples:
            raise InputError(
                f"pose {p.name!r} ({p.start_s:.2f}-{p.end_s:.2f} s) has {mini.n} samples after trimming "
                f"{trim_s} s at each end (need >= {min_samples}): hold longer or lower --trim",
                where=where,
            )
        tb = observations(mini, window_s, trim_s, min_samples=min_samples,
                          check_units=check_units, check_moving=False)  # fmt: skip
        if p.name not in names:
            names.append(p.name)
        rows.add(_table_columns(tb, names.index(p.name)))
        if stats_out is not None:
            stats_out.extend(pose_stats(mini, trim_s=trim_s, min_samples=min_samples,
                                         check_units=check_units, check_moving=False))  # fmt: skip
        if wins is not None:
            wins.add(p, *static_windows(mini.t_s, mini.accel_g))
        trim_heap()  # a hold's arrays are freed: give their pages back (calibrate.heap)

    try:
        for block in iter_imu(path):
            if on_block is not None:
                on_block(block)
            for p, parts in gather.add(block):
                reduce(p, parts)
        for p, parts in gather.finish():
            reduce(p, parts)
        if wins is not None:
            wins.judge(1.0 / meta.accel_lsb_per_g if meta.accel_lsb_per_g else 0.0, where)
    finally:
        if wins is not None:
            wins.close()
    out = _table(rows, names, where)
    trim_heap()
    return out


def _most_windows(p: PoseLabel, trim_s: float, window_s: float) -> int:
    """An upper bound on the windows of window_s in the trimmed hold (rows of observations, or of
    static_windows for 0.5 s): its samples span less than the trimmed label."""
    return int(np.floor(max(p.end_s - p.start_s - 2.0 * trim_s, 0.0) / window_s + 1e-9)) + 2


class _HoldWindows:
    """The motion check's 0.5 s windows of every hold (segment.static_windows, the mean reduced to
    its shift from the hold's median as the hold passes) spilled to an unnamed temporary file
    (calibrate.window_spill: 56 bytes a window, ~170 k windows at 24 h, kept by the page cache, not
    the process) and read back hold by hold for the verdict; the session's noise reference (the
    median std per axis of the windows of n > 2) is selected exactly from the file."""

    def __init__(self) -> None:
        self.spill = WindowSpill(7)  # start s, end s, mean shift g, std x/y/z g, samples
        self.holds: list[PoseLabel] = []
        self.sizes: list[int] = []
        self.n_ok = 0

    def add(self, p: PoseLabel, t0, t1, mean, std, n) -> None:
        self.spill.append(np.column_stack([t0, t1, mean_shift(mean), std, n]))
        self.holds.append(p)
        self.sizes.append(len(t0))
        self.n_ok += int(np.count_nonzero(n > 2))

    def _per_hold(self):
        for p, w in zip(self.holds, self.spill.runs(self.sizes), strict=True):
            yield (
                p,
                w[:, 0].copy(),
                w[:, 1].copy(),
                w[:, 2].copy(),
                w[:, 3:6].copy(),
                w[:, 6].astype(np.int64),
            )

    def judge(self, quantum: float, where: str) -> None:
        """segment.moving_check's verdict on the windows written (InputError naming the window)."""
        if self.n_ok == 0:  # no window of n > 2: no noise reference, no verdict
            return
        med = [median(self.spill.column(j, _quiet), self.n_ok) for j in (3, 4, 5)]
        moving_verdict(self._per_hold(), quantum, where, ref=float(np.linalg.norm(np.array(med))))

    def close(self) -> None:
        self.spill.close()


def _quiet(w: np.ndarray) -> np.ndarray:
    """The windows of > 2 samples of a piece of spilled rows."""
    return w[:, 6] > 2


class _Rows:
    """Columns of a table filled hold by hold in arrays allocated once (capacity: an upper bound on
    the rows; doubled should a hold exceed it), not a list of small per-hold arrays joined at the
    end: no second copy of the table and no heap fragments left by hundreds of small arrays."""

    def __init__(self, capacity: int) -> None:
        self.cap, self.n, self.cols = max(int(capacity), 1), 0, {}

    def add(self, cols: dict[str, np.ndarray]) -> None:
        k = len(next(iter(cols.values())))
        if self.n + k > self.cap:
            self.cap = max(2 * self.cap, self.n + k)
            for name, a in self.cols.items():
                grown = np.empty((self.cap, *a.shape[1:]), a.dtype)
                grown[: self.n] = a[: self.n]
                self.cols[name] = grown
        for name, v in cols.items():
            if name not in self.cols:
                self.cols[name] = np.empty((self.cap, *np.shape(v)[1:]), np.asarray(v).dtype)
            self.cols[name][self.n : self.n + k] = v
        self.n += k

    def col(self, name: str) -> np.ndarray:
        return self.cols[name][: self.n]


class _HoldGatherer:
    """Collects the samples of each trimmed hold [start + trim, end - trim) as blocks pass."""

    def __init__(self, labels: list[PoseLabel], trim_s: float) -> None:
        self.labels = labels
        self.trim_s = trim_s
        self.k = 0
        self.parts: list[tuple] = []

    def _range(self, p: PoseLabel) -> tuple[float, float]:
        t0, t1 = p.start_s + self.trim_s, p.end_s - self.trim_s
        return (t0, t1) if t1 > t0 else (t0, t0)

    def add(self, b):
        """Yield (label, parts) for every hold this block completes."""
        while self.k < len(self.labels):
            p = self.labels[self.k]
            t0, t1 = self._range(p)
            i, j = np.searchsorted(b.t_s, [t0, t1])
            if j > i:
                sl = slice(i, j)
                temp = None if b.temp_degC is None else b.temp_degC[sl]
                self.parts.append((b.t_s[sl], b.sample_index[sl], b.accel_g[sl], temp))
            if b.t_s[-1] < t1:  # the hold goes on in the next block
                return
            yield p, self.parts
            self.parts = []
            self.k += 1

    def finish(self):
        while self.k < len(self.labels):
            yield self.labels[self.k], self.parts
            self.parts = []
            self.k += 1


def _hold_session(meta: SessionMeta, p: PoseLabel, parts: list[tuple], where: str) -> Session:
    """A Session holding one trimmed hold's samples and its label."""
    if parts:
        t, si, acc = (np.concatenate([x[i] for x in parts]) for i in range(3))
        temp = None if parts[0][3] is None else np.concatenate([x[3] for x in parts])
    else:
        t, si, acc, temp = np.zeros(0), np.zeros(0, np.int64), np.zeros((0, 3)), None
    return Session(meta=meta, t_s=t, sample_index=si, accel_g=acc, temp_degC=temp, poses=[p], path=where)


def _table_columns(tb: ObsTable, pose_id: int) -> dict[str, np.ndarray]:
    """One hold's ObsTable as columns for _Rows (pose ids by first appearance, as observations)."""
    out = {"pose_id": np.full(tb.n, pose_id)}
    for f in dataclasses.fields(ObsTable):
        v = getattr(tb, f.name)
        if f.name != "pose_id" and isinstance(v, np.ndarray):
            out[f.name] = v
    return out


def _table(rows: _Rows, names: list[str], where: str) -> ObsTable:
    """The ObsTable of every hold's rows (columns no hold has are None)."""
    out = {}
    for f in dataclasses.fields(ObsTable):
        if f.name == "pose_names":
            out[f.name] = names
        elif f.name == "session":
            out[f.name] = where
        else:
            out[f.name] = rows.col(f.name) if f.name in rows.cols else None
    out["pose_id"] = out["pose_id"].astype(int)
    return ObsTable(**out)


def stream_check_timestamps(path: str | Path) -> None:
    """label_check.check_timestamps on the file's samples, block by block (the same messages)."""
    check = TimestampCheck()
    for b in iter_imu(path):
        check.add(b.t_s)
    check.finish(path)


class TimestampCheck:
    """stream_check_timestamps fed block by block (a pass that reads the samples anyway runs it)."""

    def __init__(self) -> None:
        self.n, self.t0, self.t_last, self.bad_n = 0, np.nan, np.nan, 0
        self.nonfinite = self.first_bad = None  # index of the first non-finite stamp / (i, t_i, t_i-1)

    def add(self, t_s: np.ndarray) -> None:
        t, n = np.asarray(t_s, float), self.n
        fin = ~np.isfinite(t)
        if self.nonfinite is None and fin.any():
            self.nonfinite = n + int(np.argmax(fin))
        if n and t.size and not t[0] > self.t_last:  # the step from the previous block (NaN: not bad)
            self.bad_n += int(t[0] <= self.t_last)
            if self.first_bad is None and t[0] <= self.t_last:
                self.first_bad = (n, t[0], self.t_last)
        bad = t[1:] <= t[:-1]
        nb = int(np.count_nonzero(bad))
        if nb:
            self.bad_n += nb
            if self.first_bad is None:
                j = int(np.argmax(bad)) + 1
                self.first_bad = (n + j, t[j], t[j - 1])
        if not n and t.size:
            self.t0 = t[0]
        self.n += t.size
        if t.size:
            self.t_last = t[-1]

    def finish(self, path: str | Path) -> None:
        """InputError (one line) when the stamps fed are not a session's; else nothing."""
        where, n, t0 = str(path), self.n, self.t0
        if n < 2:  # no samples to hold: read_session names a file that is not a session at all
            from accellog.store.reader import read_session

            read_session(path)
            raise InputError(f"session has {n} sample(s): nothing to calibrate", where=where)
        if self.nonfinite is not None:
            raise InputError(f"sample {self.nonfinite} has a non-finite time stamp", where=where)
        if not self.t_last > t0:
            raise InputError(f"session has zero duration ({n} samples at t = {t0:g} s)", where=where)
        if self.first_bad is not None:
            i, ti, tp = self.first_bad
            kind = "duplicated" if ti == tp else "decreasing"
            raise InputError(
                f"{kind} time stamp at sample {i}: t = {ti:.6f} s after {tp:.6f} s "
                f"({self.bad_n} non-increasing steps)",
                where=where,
            )
