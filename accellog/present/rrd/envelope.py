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

ENVELOPE_BUCKETS = 4000
"""Buckets per logged series: about the width of a plot in pixels (2 rows each)."""
FULL_RATE_MAX_SAMPLES = 20_000
"""Series with at most this many samples are logged at the full rate (an envelope would not be
much smaller); longer ones as envelopes unless the recording asks for the full rate."""


def track_keep(n: int, points: int = 2 * ENVELOPE_BUCKETS) -> np.ndarray:
    """Indices of a smooth series (a displacement track, m) kept for display: about ``points``
    evenly spaced samples plus the last one (its final value stays exact)."""
    return np.unique(np.r_[np.linspace(0, n - 1, min(n, points)).astype(np.int64), n - 1])


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


def _envelope(t: np.ndarray, v: np.ndarray, b: np.ndarray, pos: np.ndarray) -> Envelope:
    """Rows of complete buckets: t (n,), v (n,k), b bucket ids (n,, non-decreasing), pos sample idx.

    Column by column on a contiguous copy (k, n): min and max by ``reduceat``, and the first sample
    equal to each (which comes first) from the sorted positions of the equal samples."""
    n, k = v.shape
    if n == 0:
        return Envelope(np.empty(0), np.empty((0, k)), np.empty(0, np.int64), np.empty(0, np.int64))
    starts = np.flatnonzero(b[1:] != b[:-1]) + 1
    starts = np.r_[0, starts]
    ends = np.r_[starts[1:], n]  # exclusive
    counts = ends - starts
    cols = np.ascontiguousarray(v.T)  # (k, n): reduceat along contiguous rows is ~10x faster
    with np.errstate(invalid="ignore"):
        mn = np.fmin.reduceat(cols, starts, axis=1)  # (k, buckets), NaNs ignored
        mx = np.fmax.reduceat(cols, starts, axis=1)
    rows = np.empty((2 * starts.shape[0], k))
    for j in range(k):
        first_min = _first_equal(cols[j], mn[j], starts, ends, counts)
        first_max = _first_equal(cols[j], mx[j], starts, ends, counts)
        min_first = first_min <= first_max  # the min comes first (NaN buckets: both n)
        rows[0::2, j] = np.where(min_first, mn[j], mx[j])
        rows[1::2, j] = np.where(min_first, mx[j], mn[j])
    idx = np.empty(2 * starts.shape[0], dtype=np.int64)
    idx[0::2] = starts
    idx[1::2] = ends - 1
    return Envelope(t[idx], rows, pos[idx], b[idx])


def _first_equal(col: np.ndarray, ext: np.ndarray, starts, ends, counts) -> np.ndarray:
    """Per bucket, the position of the first sample of col equal to the bucket's ext (n when none:
    a bucket of only NaNs)."""
    n = col.shape[0]
    hits = np.append(np.flatnonzero(col == np.repeat(ext, counts)), n)  # sorted, n at the end
    first = hits[np.searchsorted(hits, starts)]  # the first hit at or after each bucket's start
    return np.where(first < ends, first, n)


class EnvelopeBuilder:
    """Min/max envelope of a series fed batch by batch (see the module docstring).

    t0_s: start of bucket 0 (s); width_s: bucket width (s). push() returns the rows of the buckets
    that are complete (a later sample has arrived), finish() those of the last one.
    """

    def __init__(self, t0_s: float, width_s: float) -> None:
        self.t0_s = float(t0_s)
        self.width_s = float(width_s)
        self._t: np.ndarray | None = None  # samples of the open bucket
        self._v: np.ndarray | None = None
        self._pos: np.ndarray | None = None
        self._b: np.ndarray | None = None
        self.n_in = 0

    def push(self, t_s: np.ndarray, values: np.ndarray, index: np.ndarray | None = None) -> Envelope:
        """Add samples (t_s (n,) s non-decreasing, values (n,k)); index: their sample numbers (default:
        running count)."""
        t = np.asarray(t_s, dtype=np.float64).reshape(-1)
        v = np.asarray(values, dtype=np.float64).reshape(t.shape[0], -1)
        pos = np.arange(self.n_in, self.n_in + t.shape[0]) if index is None else np.asarray(index, np.int64)
        self.n_in += t.shape[0]
        b = np.floor((t - self.t0_s) / self.width_s).astype(np.int64)
        if self._t is not None:
            t, v = np.concatenate([self._t, t]), np.concatenate([self._v, v])
            pos, b = np.concatenate([self._pos, pos]), np.concatenate([self._b, b])
        if t.shape[0] == 0:
            return _envelope(t, v, b, pos)
        cut = int(np.searchsorted(b, b[-1], side="left"))  # the last bucket may go on
        self._t, self._v, self._pos, self._b = t[cut:], v[cut:], pos[cut:], b[cut:]
        return _envelope(t[:cut], v[:cut], b[:cut], pos[:cut])

    def finish(self) -> Envelope:
        """Rows of the last (open) bucket; the builder is empty afterwards."""
        if self._t is None:
            return _envelope(np.empty(0), np.empty((0, 1)), np.empty(0, np.int64), np.empty(0, np.int64))
        t, v, pos, b = self._t, self._v, self._pos, self._b
        self._t = self._v = self._pos = self._b = None
        return _envelope(t, v, b, pos)


def minmax_envelope(
    t_s: np.ndarray, values: np.ndarray, *, buckets: int = ENVELOPE_BUCKETS, index: np.ndarray | None = None
) -> Envelope:
    """One-shot envelope of a whole series over its own time span (buckets of span / buckets s)."""
    t = np.asarray(t_s, dtype=np.float64).reshape(-1)
    if t.shape[0] == 0:
        v = np.asarray(values, dtype=np.float64).reshape(0, -1)
        return _envelope(t, v, np.empty(0, np.int64), np.empty(0, np.int64))
    eb = EnvelopeBuilder(float(t[0]), bucket_width_s(float(t[-1] - t[0]), buckets))
    first = eb.push(t, values, index)
    last = eb.finish()
    return Envelope(
        np.r_[first.t_s, last.t_s],
        np.concatenate([first.values, last.values]),
        np.r_[first.row_index, last.row_index],
        np.r_[first.bucket, last.bucket],
    )
