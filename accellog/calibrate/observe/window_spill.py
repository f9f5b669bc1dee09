"""Per-window statistics spilled to an unnamed temporary file, and exact order statistics over a
spilled column in bounded memory (the motion checks' session medians: ``stream_segment`` for the
observation pass, ``motion.MotionCheck`` for a static test).

Rows of a fixed number of float64 columns are appended as they are made (in the page cache, not
held in the process) and read back in order a piece at a time. A median is found exactly by a
radix selection over the file: a few passes, each counting the values by 16 bits of their
order-preserving bit pattern, until the bucket holding the wanted rank is small enough to be read
and partitioned (at most SELECT_CAP values in memory). ``median`` equals np.median of the whole
column (the middle value, or the mean of the two middle ones; NaN if any value is NaN).
"""

from __future__ import annotations

import io
import tempfile
from collections.abc import Callable, Iterator

import numpy as np

PIECE_BYTES = 1 << 21
"""Bytes read back at a time (2 MB)."""
SELECT_CAP = 1 << 16
"""A selection bucket with at most this many values is read and partitioned in memory."""
_TOP = np.uint64(1 << 63)

Values = Callable[[], Iterator[np.ndarray]]
"""A column's values in pieces, the same on every call."""


class WindowSpill:
    """Rows of `cols` float64 appended to an anonymous temporary file (in memory when no temporary
    directory is writable), read back in order a piece at a time."""

    def __init__(self, cols: int) -> None:
        try:
            # unlinked at creation: closed by close(), or when collected after an error
            self.f: io.IOBase = tempfile.TemporaryFile(prefix="accellog-windows-")  # noqa: SIM115
        except OSError:
            self.f = io.BytesIO()
        self.cols, self.n = cols, 0

    def append(self, rows: np.ndarray) -> None:
        rows = np.ascontiguousarray(rows, dtype=np.float64).reshape(-1, self.cols)
        self.f.write(rows.data)
        self.n += rows.shape[0]

    def pieces(self, rows: int | None = None) -> Iterator[np.ndarray]:
        """(m, cols) arrays of every row, in the order appended (rows a piece: ~PIECE_BYTES)."""
        rows = rows or max(PIECE_BYTES // (8 * self.cols), 1)
        self.f.flush()
        self.f.seek(0)
        while raw := self.f.read(rows * self.cols * 8):
            yield np.frombuffer(raw, np.float64).reshape(-1, self.cols)
        self.f.seek(0, io.SEEK_END)

    def runs(self, lengths: list[int]) -> Iterator[np.ndarray]:
        """(lengths[i], cols) arrays: the rows in order, cut into runs of the given lengths."""
        self.f.flush()
        self.f.seek(0)
        for k in lengths:
            yield np.frombuffer(self.f.read(k * self.cols * 8), np.float64).reshape(-1, self.cols)
        self.f.seek(0, io.SEEK_END)

    def column(self, j: int, keep: Callable[[np.ndarray], np.ndarray] | None = None) -> Values:
        """Column j of every row (of the rows where keep(piece) is True, when given)."""

        def values() -> Iterator[np.ndarray]:
            for p in self.pieces():
                yield p[:, j] if keep is None else p[keep(p), j]

        return values

    def close(self) -> None:
        self.f.close()


def _keys(x: np.ndarray) -> np.ndarray:
    """uint64 keys ordered as the floats x (not NaN; -0.0 just below +0.0)."""
    u = np.ascontiguousarray(x, np.float64).view(np.uint64)
    return np.where(u >= _TOP, ~u, u | _TOP)


def _value(key: int) -> float:
    u = np.uint64(key)
    u = u & ~_TOP if u >= _TOP else ~u
    return float(np.array([u], np.uint64).view(np.float64)[0])


def kth_smallest(values: Values, k: int, cap: int = SELECT_CAP) -> float:
    """The k-th smallest (0-based) of the floats that values() yields (the same on every call, in
    pieces): what np.partition(all, k)[k] gives, in memory bounded by the pieces and cap; NaN if
    any value is NaN (np.median's answer then)."""
    prefix, mask = np.uint64(0), np.uint64(0)
    for shift in (48, 32, 16, 0):
        counts = np.zeros(1 << 16, np.int64)
        for x in values():
            if not mask and np.isnan(x).any():
                return float("nan")
            key = _keys(x)
            if mask:
                key = key[(key & mask) == prefix]
            counts += np.bincount(((key >> np.uint64(shift)) & np.uint64(0xFFFF)).astype(np.intp),
                                  minlength=1 << 16)  # fmt: skip
        cum = np.cumsum(counts)
        d = int(np.searchsorted(cum, k, side="right"))
        k -= int(cum[d - 1]) if d else 0
        prefix |= np.uint64(d) << np.uint64(shift)
        mask |= np.uint64(0xFFFF) << np.uint64(shift)
        if shift and counts[d] <= cap:
            sel = [x[(_keys(x) & mask) == prefix] for x in values()]
            return float(np.partition(np.concatenate(sel), k)[k])
    return _value(int(prefix))  # every value left in the bucket has this bit pattern


def median(values: Values, n: int) -> float:
    """np.median of the n floats values() yields: the middle one, or the mean of the middle two."""
    if n % 2:
        return float(np.mean(np.array([kth_smallest(values, n // 2)])))
    lo, hi = kth_smallest(values, n // 2 - 1), kth_smallest(values, n // 2)
    return float(np.mean(np.array([lo, hi])))
