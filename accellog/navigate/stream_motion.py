"""The motion check of a streamed static hold (``segment.check_static``'s verdict) in memory bounded
independently of the session length.

The check cuts the hold into 0.5 s windows and needs two session medians at the end: the window
std per axis (windows of > 2 samples: the noise reference) and the window mean per axis (a window
moves when its mean leaves it). Each block's windows (start s, end s, mean g (3), std g (3), count)
are written to a temporary file as they are made (72 bytes a window, in the page cache, not held in
the process), and the medians are found exactly by a radix selection over that file: a few passes,
each counting the values by 16 bits of their order-preserving bit pattern, until the bucket holding
the wanted rank is small enough to be read and partitioned (at most SELECT_CAP values in memory).
The verdict, its window and its message equal ``segment.moving_check``'s on the whole window table
(np.median: the middle value, or the mean of the two middle ones); tests compare them.
"""

from __future__ import annotations

import io
import tempfile
from collections.abc import Callable, Iterator

import numpy as np

from accellog.calibrate.segment import MOVING_MEAN_SHIFT_G, MOVING_STD_FACTOR, _window_stats, moving_error
from accellog.navigate.stream_sums import WindowCarry

COLS = 9
"""Spilled columns per window: start s, end s, mean x/y/z g, std x/y/z g, count."""
PIECE_ROWS = 1 << 15
"""Windows read back at a time (2.4 MB)."""
SELECT_CAP = 1 << 16
"""A selection bucket with at most this many values is read and partitioned in memory."""
_TOP = np.uint64(1 << 63)


class WindowSpill:
    """Rows of COLS float64 appended to an anonymous temporary file (in memory when no temporary
    directory is writable), read back in order a piece at a time."""

    def __init__(self) -> None:
        try:
            # unlinked at creation: closed by close(), or when collected after an error
            self.f: io.IOBase = tempfile.TemporaryFile(prefix="accellog-windows-")  # noqa: SIM115
        except OSError:
            self.f = io.BytesIO()
        self.n = 0

    def append(self, rows: np.ndarray) -> None:
        rows = np.ascontiguousarray(rows, dtype=np.float64)
        self.f.write(rows.data)
        self.n += rows.shape[0]

    def pieces(self, rows: int = PIECE_ROWS) -> Iterator[np.ndarray]:
        """(m, COLS) arrays of every row, in the order appended."""
        self.f.flush()
        self.f.seek(0)
        while raw := self.f.read(rows * COLS * 8):
            yield np.frombuffer(raw, np.float64).reshape(-1, COLS)
        self.f.seek(0, io.SEEK_END)

    def close(self) -> None:
        self.f.close()


def _keys(x: np.ndarray) -> np.ndarray:
    """uint64 keys ordered as the floats x (finite; -0.0 just below +0.0)."""
    u = np.ascontiguousarray(x, np.float64).view(np.uint64)
    return np.where(u >= _TOP, ~u, u | _TOP)


def _value(key: int) -> float:
    u = np.uint64(key)
    u = u & ~_TOP if u >= _TOP else ~u
    return float(np.array([u], np.uint64).view(np.float64)[0])


def kth_smallest(values: Callable[[], Iterator[np.ndarray]], k: int, cap: int = SELECT_CAP) -> float:
    """The k-th smallest (0-based) of the finite floats that values() yields (the same on every call,
    in pieces): what np.partition(all, k)[k] gives, in memory bounded by the pieces and cap."""
    prefix, mask = np.uint64(0), np.uint64(0)
    for shift in (48, 32, 16, 0):
        counts = np.zeros(1 << 16, np.int64)
        for x in values():
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


def median(values: Callable[[], Iterator[np.ndarray]], n: int) -> float:
    """np.median of the n finite floats values() yields: the middle one, or the mean of the middle two."""
    if n % 2:
        return float(np.mean(np.array([kth_smallest(values, n // 2)])))
    lo, hi = kth_smallest(values, n // 2 - 1), kth_smallest(values, n // 2)
    return float(np.mean(np.array([lo, hi])))


class MotionCheck:
    """check_static's 0.5 s windows of the raw reading (g), spilled block by block (module doc)."""

    def __init__(self, width_s: float = 0.5) -> None:
        self.cut = WindowCarry(width_s)
        self.spill = WindowSpill()

    def add(self, t: np.ndarray, acc: np.ndarray) -> None:
        self._take(self.cut.push(t, acc))

    def _take(self, out) -> None:
        if out is None:
            return
        t, (acc,), starts = out
        mean, std, n = _window_stats(acc, starts)
        ends = np.append(starts[1:] - 1, t.shape[0] - 1)
        self.spill.append(np.column_stack([t[starts], t[ends], mean, std, n]))

    def check(self, quantum: float, where: str, name: str = "static test") -> None:
        """segment.moving_check of the hold `name` over every window added (InputError: it moves)."""
        self._take(self.cut.flush())
        try:
            self._verdict(quantum, where, name)
        finally:
            self.spill.close()

    def _column(self, j: int, quiet_only: bool) -> Callable[[], Iterator[np.ndarray]]:
        def values() -> Iterator[np.ndarray]:
            for p in self.spill.pieces():
                yield p[p[:, 8] > 2, j] if quiet_only else p[:, j]

        return values

    def _verdict(self, quantum: float, where: str, name: str) -> None:
        n_quiet = sum(int(np.count_nonzero(p[:, 8] > 2)) for p in self.spill.pieces())
        if n_quiet == 0:  # moving_check: no noise reference, no verdict
            return
        ref = float(np.linalg.norm(np.array([median(self._column(j, True), n_quiet) for j in (5, 6, 7)])))
        med = np.array([median(self._column(j, False), self.spill.n) for j in (2, 3, 4)])
        limit = max(MOVING_STD_FACTOR * ref, 4.0 * quantum)
        for p in self.spill.pieces():
            std, mean, n = np.ascontiguousarray(p[:, 5:8]), np.ascontiguousarray(p[:, 2:5]), p[:, 8]
            snorm = np.linalg.norm(std, axis=1)
            shift = np.linalg.norm(mean - med, axis=1)
            bad_std = (snorm > limit) & (n > 2)
            bad = bad_std | (shift > MOVING_MEAN_SHIFT_G)
            if bad.any():
                j = int(np.argmax(bad))
                raise moving_error(
                    name, p[j, 0], p[j, 1], snorm[j] if bad_std[j] else None, shift[j], ref, where
                )
