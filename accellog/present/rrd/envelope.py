"""Display envelopes of long series: min and max per pixel-scale time bucket.

A session of any length is drawn with about ``ENVELOPE_BUCKETS`` buckets per view. Sample i falls in
bucket

    b_i = floor((t_i - t0) / w),    w = span_s / ENVELOPE_BUCKETS     (s)

and every bucket that holds samples is logged as two rows: at the time of its first sample and at
the time of its last sample (real sample times, increasing). Per column, the first row holds the
extreme (min or max) that occurs first in the bucket and the second row the other one, so a line
through the rows keeps the signal's shape and every bucket's min and max stay exact: spikes and
clipping remain visible whatever the zoom-out (plain striding keeps every k-th sample and drops
them). NaNs are ignored (a bucket of only NaNs gives NaN rows).

``EnvelopeBuilder`` takes a series batch by batch (replay, streaming) and carries the bucket that is
still open across calls, so the result does not depend on how the series was cut; memory is one
bucket. ``minmax_envelope`` is the one-shot form.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from accellog.core.timeseries import even_indices

ENVELOPE_BUCKETS = 4000
"""Buckets per logged series: about the width of a plot in pixels (2 rows each)."""
FULL_RATE_MAX_SAMPLES = 20_000
"""Series with at most this many samples are logged at the full rate (an envelope would not be
much smaller); longer ones as envelopes unless the recording asks for the full rate."""
LOOP_MIN_SAMPLES = 64
"""Buckets of this many samples or more (on average) are reduced one by one (``_bucket_extremes``):
a 60 s batch at 1 kHz (67 buckets, 3 columns) 0.27 ms instead of 1.7 ms for the transposed copy
and the padded (k, buckets, longest) gather; shorter ones all at once, where a Python loop per
bucket would cost more than the copies."""


def track_keep(n: int, points: int = 2 * ENVELOPE_BUCKETS) -> np.ndarray:
    """Indices of a smooth series (a displacement track, m) kept for display: about ``points``
    evenly spaced samples plus the last one (its final value stays exact)."""
    return even_indices(n, points)


def bucket_width_s(span_s: float, buckets: int = ENVELOPE_BUCKETS) -> float:
    """Bucket width (s) for a series spanning span_s seconds (> 0 even for a single instant)."""
    span = float(span_s)
    return span / buckets if np.isfinite(span) and span > 0 else 1.0


@dataclass
class Envelope:
    """Envelope rows: times (2 per bucket, s), values (2 per bucket, k columns), and the index of
    each row's sample (for the ``sample`` timeline), plus the bucket number of each row."""

    t_s: np.ndarray
    values: np.ndarray
    row_index: np.ndarray
    bucket: np.ndarray

    @property
    def n(self) -> int:
        return int(self.t_s.shape[0])


def _envelope(t: np.ndarray, v: np.ndarray, pos, starts: np.ndarray, ids: np.ndarray) -> Envelope:
    """Rows of complete buckets: t (n,) s, v (n,k), pos the sample numbers (n,) or the number of the
    first sample (int, then counted on); starts: first sample of each bucket (increasing, from 0), ids
    their bucket numbers.

    The first min and max of each bucket: bucket by bucket (``_bucket_extremes``) when buckets are
    long, else column by column on a contiguous copy (k, n) (``_arg_extremes``); when a bucket holds a
    NaN, min and max by ``fmin/fmax.reduceat`` (NaNs ignored) and the first sample equal to each from
    the sorted positions of the equal samples."""
    n, k = v.shape
    if n == 0:
        return Envelope(np.empty(0), np.empty((0, k)), np.empty(0, np.int64), np.empty(0, np.int64))
    nb = starts.shape[0]
    ends = np.empty_like(starts)  # exclusive
    ends[:-1], ends[-1] = starts[1:], n
    counts = ends - starts
    cols = None
    if n >= LOOP_MIN_SAMPLES * nb:
        found = _bucket_extremes(v, starts, ends)
    else:
        cols = np.ascontiguousarray(v.T)  # (k, n): reductions along contiguous rows are ~10x faster
        found = _arg_extremes(cols, starts, counts)
    if found is not None:
        mn, mx, min_first = found
    else:
        if cols is None:
            cols = np.ascontiguousarray(v.T)
        with np.errstate(invalid="ignore"):
            mn = np.fmin.reduceat(cols, starts, axis=1)  # (k, buckets), NaNs ignored
            mx = np.fmax.reduceat(cols, starts, axis=1)
        first = [_first_equal(cols, ext, starts, ends, counts) for ext in (mn, mx)]
        min_first = first[0] <= first[1]
    rows = np.empty((2 * nb, k))
    rows[0::2] = np.where(min_first, mn, mx).T  # the extreme that comes first (NaN buckets: NaN)
    rows[1::2] = np.where(min_first, mx, mn).T
    idx = np.empty(2 * nb, dtype=np.int64)
    idx[0::2], idx[1::2] = starts, ends - 1
    row_index = idx + pos if isinstance(pos, (int, np.integer)) else np.asarray(pos, np.int64)[idx]
    return Envelope(t[idx], rows, row_index, np.asarray(ids, np.int64).repeat(2))


def _bucket_extremes(v: np.ndarray, starts: np.ndarray, ends: np.ndarray):
    """(min, max, min comes first) per column and bucket (k, buckets) of v (n, k) from an ``argmin``
    and an ``argmax`` of each bucket's rows in turn: no copy of the series. None when a bucket holds
    a NaN (argmin and argmax stop at the first NaN)."""
    nb, k = starts.shape[0], v.shape[1]
    i_mn, i_mx = np.empty((nb, k), np.intp), np.empty((nb, k), np.intp)
    for j, (a, z) in enumerate(zip(starts.tolist(), ends.tolist(), strict=True)):
        part = v[a:z]
        part.argmin(axis=0, out=i_mn[j])
        part.argmax(axis=0, out=i_mx[j])
    col = np.arange(k)
    mn, mx = v[starts[:, None] + i_mn, col], v[starts[:, None] + i_mx, col]
    if np.isnan(mn).any() or np.isnan(mx).any():
        return None
    return mn.T, mx.T, (i_mn <= i_mx).T


def _arg_extremes(cols: np.ndarray, starts: np.ndarray, counts: np.ndarray):
    """(min, max, min comes first) per column and bucket (k, buckets) of cols (k, n) from one
    ``argmin`` and one ``argmax`` pass over the buckets laid side by side (k, buckets, longest): a
    view when every bucket has the same length, else a copy with each bucket padded with its own last
    sample (a repeat after the end cannot be a first extreme). None when a bucket holds a NaN (argmin
    and argmax stop at the first NaN) or when padding would more than double the samples."""
    k, n = cols.shape
    nb, c = starts.shape[0], int(counts.max())
    if nb * c > 2 * n:
        return None
    if int(counts.min()) == c:
        g = cols.reshape(k, nb, c)
    else:
        g = cols.take(np.minimum(starts[:, None] + np.arange(c), (starts + counts - 1)[:, None]), axis=1)
    i_mn, i_mx = g.argmin(axis=2), g.argmax(axis=2)
    flat, row = g.reshape(-1), np.arange(0, k * nb * c, c).reshape(k, nb)
    mn, mx = flat[row + i_mn], flat[row + i_mx]
    if np.isnan(mn).any() or np.isnan(mx).any():
        return None
    return mn, mx, i_mn <= i_mx


def _first_equal(cols: np.ndarray, ext: np.ndarray, starts, ends, counts) -> np.ndarray:
    """Per column and bucket (k, buckets), the first sample of cols (k, n) equal to ext (k, buckets),
    as a flat position j n + i (k n when there is none: a bucket of only NaNs)."""
    k, n = cols.shape
    hits = np.flatnonzero(cols == ext.repeat(counts, axis=1))  # increasing flat positions
    if hits.shape[0] == 0:
        return np.full(ext.shape, k * n)
    row = (np.arange(k) * n)[:, None]
    first = hits.take(hits.searchsorted(row + starts), mode="clip")  # first hit at or after each start
    return np.where((first >= row + starts) & (first < row + ends), first, k * n)


class EnvelopeBuilder:
    """Min/max envelope of a series fed batch by batch (see the module docstring).

    t0_s: start of bucket 0 (s); width_s: bucket width (s). push() returns the rows of the buckets
    that are complete (a later sample has arrived), finish() those of the last one.
    """

    def __init__(self, t0_s: float, width_s: float) -> None:
        self.t0_s = float(t0_s)
        self.width_s = float(width_s)
        self._open: tuple | None = None  # the open bucket: (t, v, pos, bucket number), copies
        self.n_in = 0

    def bucket(self, t_s: np.ndarray) -> np.ndarray:
        """Bucket number floor((t - t0) / w) of each time (s)."""
        return np.floor((np.asarray(t_s, dtype=np.float64) - self.t0_s) / self.width_s).astype(np.int64)

    def starts(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(first sample of each bucket in t, its bucket number) for times t (s, non-decreasing).

        The bucket edges are searched in t and moved to where ``bucket`` changes, so only the
        samples next to an edge are bucketed (all of them when that does not settle quickly)."""
        n = t.shape[0]
        lo, hi = self.bucket(t[[0, -1]])
        if hi - lo <= n:  # else a jump in time: at most n buckets hold samples
            ks = np.arange(lo + 1, hi + 1)
            p = np.searchsorted(t, self.t0_s + ks * self.width_s)  # near the first sample with b >= k
            for _ in range(4):  # b is non-decreasing: step each edge until b[p - 1] < k <= b[p]
                down = (p > 0) & (self.bucket(t[np.maximum(p - 1, 0)]) >= ks)
                up = (p < n) & (self.bucket(t[np.minimum(p, n - 1)]) < ks)
                if not (down.any() or up.any()):
                    p = p[np.diff(p, prepend=0) > 0]  # empty buckets share an edge
                    starts = np.concatenate([[0], p])
                    return starts, self.bucket(t[starts])
                p = p - down + up
        b = self.bucket(t)
        starts = np.concatenate([[0], np.flatnonzero(b[1:] != b[:-1]) + 1])
        return starts, b[starts]

    def push(
        self,
        t_s: np.ndarray,
        values: np.ndarray,
        index: np.ndarray | None = None,
        edges: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> Envelope:
        """Add samples (t_s (n,) s non-decreasing, values (n,k)); index: their sample numbers (default:
        running count); edges: ``starts(t_s)`` when already known (series of one batch sharing its
        times and this builder's buckets)."""
        t = np.asarray(t_s, dtype=np.float64).reshape(-1)
        v = np.asarray(values, dtype=np.float64).reshape(t.shape[0], -1)
        n = t.shape[0]
        pos = self.n_in if index is None else np.asarray(index, np.int64).reshape(-1)
        self.n_in += n
        if n == 0:
            return _envelope(t, v, 0, np.empty(0, np.int64), np.empty(0, np.int64))
        starts, ids = self.starts(t) if edges is None else edges
        head = None  # rows of the bucket left open by the previous push, now complete
        if self._open is not None:
            ot, ov, op, oid = self._open
            self._open = None
            if ids[0] == oid:  # the open bucket goes on into this batch
                e = starts[1] if starts.shape[0] > 1 else n
                ot, ov = np.concatenate([ot, t[:e]]), np.concatenate([ov, v[:e]])
                op = np.concatenate([op, np.arange(pos, pos + e) if isinstance(pos, int) else pos[:e]])
                if e == n:
                    self._open = (ot, ov, op, oid)
                    return _envelope(t[:0], v[:0], 0, starts[:0], ids[:0])
                starts, ids = starts[1:], ids[1:]
            head = _envelope(ot, ov, op, np.zeros(1, np.int64), np.array([oid]))
        a, z = int(starts[0]), int(starts[-1])  # complete buckets: samples a..z-1; z.. stay open
        p_open = np.arange(pos + z, pos + n) if isinstance(pos, int) else pos[z:]
        self._open = (t[z:].copy(), v[z:].copy(), p_open.copy(), ids[-1])
        p_done = pos + a if isinstance(pos, int) else pos[a:z]
        rows = _envelope(t[a:z], v[a:z], p_done, starts[:-1] - a, ids[:-1])
        return rows if head is None else _concat(head, rows)

    def finish(self) -> Envelope:
        """Rows of the last (open) bucket; the builder is empty afterwards."""
        if self._open is None:
            return _envelope(np.empty(0), np.empty((0, 1)), 0, np.empty(0, np.int64), np.empty(0, np.int64))
        t, v, pos, oid = self._open
        self._open = None
        return _envelope(t, v, pos, np.zeros(1, np.int64), np.array([oid]))


def _concat(a: Envelope, b: Envelope) -> Envelope:
    return Envelope(*(np.concatenate([x, y]) for x, y in zip(_fields(a), _fields(b), strict=True)))


def _fields(e: Envelope) -> tuple[np.ndarray, ...]:
    return e.t_s, e.values, e.row_index, e.bucket


def minmax_envelope(
    t_s: np.ndarray, values: np.ndarray, *, buckets: int = ENVELOPE_BUCKETS, index: np.ndarray | None = None
) -> Envelope:
    """One-shot envelope of a whole series over its own time span (buckets of span / buckets s)."""
    t = np.asarray(t_s, dtype=np.float64).reshape(-1)
    if t.shape[0] == 0:
        v = np.asarray(values, dtype=np.float64).reshape(0, -1)
        return _envelope(t, v, 0, np.empty(0, np.int64), np.empty(0, np.int64))
    eb = EnvelopeBuilder(float(t[0]), bucket_width_s(float(t[-1] - t[0]), buckets))
    return _concat(eb.push(t, values, index), eb.finish())
