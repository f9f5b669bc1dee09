"""Stage 'segment': the observation table (and per-hold statistics) of a session's labelled holds,
made from its samples as blocks in time order (``segment_blocks``, called by ``segment.observations``
over a ``store.source.Source``): an MCAP file chunk by chunk (memory bounded by two holds of at most
SPILL_ROWS samples plus one chunk group, whatever the session's or the holds' length) or a whole Session in memory as a single block.

The labels are checked first (``holds.checked_labels``); the samples then pass and each trimmed
hold [start + trim_s, end - trim_s) is gathered until it ends (``holds.HoldSamples``: from a file,
a hold longer than SPILL_ROWS samples goes on in a temporary file, so memory is bounded whatever
the holds' length), checked (``holds.check_hold``: unit up vector, min_samples, finite readings:
refused at once), reduced to its observation rows and statistics (``holds.reduce_hold``), then
dropped. The session-wide checks
run when every hold has passed, in this order: wrong units (|mean| far from 1 g: the first such
hold), labels that contradict the measured gravity (``label_check``: the first and how many more)
and motion (``motion``: every hold's 0.5 s windows, spilled to a temporary file as they pass,
judged against the median window noise of all holds). Window statistics (means, standard
deviations, autocorrelation time) are sufficient for the fit, the diagnosis and the
cross-validation, which all take the ObsTable. A hold is reduced on a worker thread while the next
blocks are read (``_Behind``; a Session in memory, one block, is reduced in the caller's thread: 1 h
in memory took 0.32-0.33 s either way, and a short session paid the thread start).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import Future
from typing import Any

import numpy as np

from accellog.calibrate.observe.holds import (
    SPILL_ROWS,
    HoldSamples,
    PoseStats,
    check_hold,
    check_window,
    checked_labels,
    first_pass,
    meta_quantum_g,
    reduce_hold,
    units_error,
)
from accellog.calibrate.observe.label_check import hold_mismatch, mismatch_error
from accellog.calibrate.observe.motion import mean_shift, moving_verdict
from accellog.calibrate.observe.window_spill import WindowSpill, median
from accellog.core.errors import InputError
from accellog.core.heap import trim_heap
from accellog.core.session import ObsTable, PoseLabel, SessionMeta


def segment_blocks(
    meta: SessionMeta,
    poses: Sequence[PoseLabel],
    blocks: Iterable,
    window_s: float | None = 2.0,
    trim_s: float = 0.5,
    *,
    where: str,
    name: str | None = None,
    events: Sequence = (),
    min_samples: int = 20,
    check_units: bool = True,
    check_moving: bool = True,
    stats_out: list[PoseStats] | None = None,
    on_block: Callable | None = None,
    release: bool = True,
    threaded: bool = True,
) -> ObsTable | None:
    """The ObsTable of the holds labelled by poses (one row per window of about window_s (s) in
    every hold trimmed by trim_s (s) at both ends; None when window_s is None: statistics only)
    from blocks (objects with t_s (s), accel_g (g) and temp_degC (degC or None), in time order);
    where names the session in refusals (InputError), name the table's session (default where).
    stats_out (a list), when given, receives every hold's PoseStats; on_block(block) is called with
    every block (e.g. a TimestampCheck); release: give the heap's free pages back after each hold
    (heap.trim_heap, for a long file); threaded: each hold reduced on a worker thread while the
    next blocks are read (False: in the caller's thread, for a Session in memory: one block)."""
    if window_s is not None:
        check_window(window_s, meta.sample_rate_hz, where)
    labels = checked_labels(poses, where, events)
    holds = _Holds(meta, labels, window_s, trim_s, where, min_samples, check_units, check_moving, stats_out)
    gather = _HoldGatherer(labels, trim_s, SPILL_ROWS if threaded else None)

    def reduce(p, samples) -> None:
        try:
            holds.add(p, samples)
        finally:
            samples.close()
        if release:
            trim_heap()  # a hold's arrays are freed: give their pages back (core.heap)

    try:
        with _Behind(threaded) as behind:
            for block in blocks:
                if on_block is not None:
                    on_block(block)
                for p, samples in gather.add(block):
                    behind.submit(reduce, p, samples)
            for p, samples in gather.finish():
                behind.submit(reduce, p, samples)
        holds.judge()
    finally:
        holds.close()
    out = None if window_s is None else holds.table(name or where)
    if release:
        trim_heap()
    return out


class _Behind:
    """Each hold reduced on a worker thread while the next blocks are read (numpy's FFTs and
    reductions release the GIL): one hold at a time, in order, so memory holds at most two holds.
    An exception of a hold is raised before any later one of the reading (the order of a sequential
    pass). Streaming 1 h at 1 kHz (12 holds, ``open_labelled``): 0.92-1.11 s -> 0.72-0.81 s wall,
    the same CPU; the table is bit for bit the sequential one."""

    def __init__(self, threaded: bool = True) -> None:
        from accellog.core.threads import pool

        self.pool = pool(1, threaded)
        self.pending: Future | None = None

    def wait(self) -> None:
        f, self.pending = self.pending, None
        if f is not None:
            try:
                f.result()
            finally:
                del f  # else its exception's traceback holds this frame, which holds f: a cycle

    def submit(self, fn, *args) -> None:
        self.wait()
        self.pending = self.pool.submit(fn, *args)

    def __enter__(self) -> _Behind:
        return self

    def __exit__(self, *exc) -> None:
        try:
            self.wait()
        finally:
            self.pool.shutdown()


class _Holds:
    """segment_blocks' reduction of each gathered hold and the session-wide verdicts (module doc)."""

    def __init__(self, meta: SessionMeta, labels: list[PoseLabel], window_s: float | None, trim_s: float,
                 where: str, min_samples: int, check_units: bool, check_moving: bool,
                 stats_out: list[PoseStats] | None) -> None:  # fmt: skip
        self.window_s, self.trim_s, self.where, self.min_samples = window_s, trim_s, where, min_samples
        self.check_units, self.stats_out = check_units, stats_out
        self.quantum = meta_quantum_g(meta)
        rows = 0 if window_s is None else sum(_most_windows(p, trim_s, window_s) for p in labels)
        self.rows = _Rows(rows)
        self.wins = _HoldWindows() if check_moving else None
        self.names: list[str] = []
        self.units: InputError | None = None  # the first hold far from 1 g
        self.mismatches: list = []  # label_check.LabelMismatch of every hold far from its label

    def add(self, p: PoseLabel, samples: HoldSamples) -> None:
        """Check and reduce one trimmed hold (holds.first_pass, then holds.reduce_hold)."""
        first = first_pass(samples)
        check_hold(p, first, self.trim_s, self.min_samples, self.where)
        if self.check_units:
            if self.units is None:
                self.units = units_error(p, first.mean, self.where)
            bad = hold_mismatch(p, first.mean)
            if bad is not None:
                self.mismatches.append(bad)
        if self.units is not None or self.mismatches:  # refused when every hold has passed
            return
        red = reduce_hold(p, samples, first, window_s=self.window_s, quantum=self.quantum,
                          motion_window_s=0.5 if self.wins is not None else None,
                          stats=self.stats_out is not None)  # fmt: skip
        if self.wins is not None and red.windows is not None:
            self.wins.add(p, *red.windows)
        if red.rows is not None:
            if p.name not in self.names:
                self.names.append(p.name)
            cols = red.rows
            self.rows.add({"pose_id": np.full(len(cols["t_s"]), self.names.index(p.name)), **cols})
        if self.stats_out is not None and red.stats is not None:
            self.stats_out.append(red.stats)

    def judge(self) -> None:
        """The session-wide refusals, in order: units, labels, motion (InputError)."""
        if self.units is not None:
            raise self.units
        err = mismatch_error(self.mismatches, self.where)
        if err is not None:
            raise err
        if self.wins is not None:
            self.wins.judge(self.quantum, self.where)

    def table(self, name: str) -> ObsTable:
        """The ObsTable of every hold's rows (columns no hold has are None)."""
        out: dict[str, Any] = {}  # ObsTable's fields
        for f in dataclasses.fields(ObsTable):
            if f.name == "pose_names":
                out[f.name] = self.names
            elif f.name == "session":
                out[f.name] = name
            else:
                out[f.name] = self.rows.col(f.name) if f.name in self.rows.cols else None
        out["pose_id"] = out["pose_id"].astype(int)
        return ObsTable(**out)

    def close(self) -> None:
        if self.wins is not None:
            self.wins.close()


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
        refusal = moving_verdict(self._per_hold(), quantum, where, ref=float(np.linalg.norm(np.array(med))))
        if refusal is not None:
            raise refusal

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
        self.cap, self.n = max(int(capacity), 1), 0
        self.cols: dict[str, np.ndarray] = {}

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
    """Collects the samples of each trimmed hold [start + trim, end - trim) as blocks pass
    (holds.HoldSamples; spill_rows: theirs)."""

    def __init__(self, labels: list[PoseLabel], trim_s: float, spill_rows: int | None = None) -> None:
        self.labels = labels
        self.trim_s = trim_s
        self.k = 0
        self.spill_rows = spill_rows
        self.samples = HoldSamples(spill_rows)

    def _range(self, p: PoseLabel) -> tuple[float, float]:
        t0, t1 = p.start_s + self.trim_s, p.end_s - self.trim_s
        return (t0, t1) if t1 > t0 else (t0, t0)

    def _next(self) -> HoldSamples:
        done, self.samples = self.samples, HoldSamples(self.spill_rows)
        self.k += 1
        return done

    def add(self, b):
        """Yield (label, HoldSamples) for every hold this block completes."""
        if b.t_s.shape[0] == 0:
            return
        while self.k < len(self.labels):
            p = self.labels[self.k]
            t0, t1 = self._range(p)
            i, j = np.searchsorted(b.t_s, [t0, t1])
            if j > i:
                sl = slice(i, j)
                self.samples.add(b.t_s[sl], b.accel_g[sl], None if b.temp_degC is None else b.temp_degC[sl])
            if b.t_s[-1] < t1:  # the hold goes on in the next block
                return
            yield p, self._next()

    def finish(self):
        while self.k < len(self.labels):
            yield self.labels[self.k], self._next()
