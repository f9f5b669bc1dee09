"""The motion check of a streamed static hold (``segment.check_static``'s verdict) in memory bounded
independently of the session length.

The check cuts the hold into 0.5 s windows and needs two session medians at the end: the window
std per axis (windows of > 2 samples: the noise reference) and the window mean per axis (a window
moves when its mean leaves it). Each block's windows (start s, end s, mean g (3), std g (3), count)
are written to a temporary file as they are made (72 bytes a window, in the page cache, not held in
the process; ``calibrate.window_spill``), and the medians are found exactly by its radix selection
over that file (bounded memory).
The verdict, its window and its message equal ``segment.moving_check``'s on the whole window table
(np.median: the middle value, or the mean of the two middle ones); tests compare them.
"""

from __future__ import annotations

import numpy as np

from accellog.calibrate.observe.segment import (
    MOVING_MEAN_SHIFT_G,
    MOVING_STD_FACTOR,
    moving_error,
    window_stats,
)
from accellog.calibrate.observe.window_spill import WindowSpill, median
from accellog.core.errors import InputError
from accellog.navigate.stream_sums import WindowCarry

COLS = 9
"""Spilled columns per window: start s, end s, mean x/y/z g, std x/y/z g, count."""


class MotionCheck:
    """check_static's 0.5 s windows of the raw reading (g), spilled block by block (module doc)."""

    def __init__(self, width_s: float = 0.5) -> None:
        self.cut = WindowCarry(width_s)
        self.spill = WindowSpill(COLS)

    def add(self, t: np.ndarray, acc: np.ndarray) -> None:
        self._take(self.cut.push(t, acc))

    def _take(self, out) -> None:
        if out is None:
            return
        t, (acc,), starts = out
        mean, std, n = window_stats(acc, starts)
        ends = np.append(starts[1:] - 1, t.shape[0] - 1)
        self.spill.append(np.column_stack([t[starts], t[ends], mean, std, n]))

    def check(self, quantum: float, where: str, name: str = "static test") -> None:
        """segment.moving_check of the hold `name` over every window added (InputError: it moves)."""
        refusal = self.refusal(quantum, where, name)
        if refusal is not None:
            raise refusal

    def refusal(self, quantum: float, where: str, name: str = "static test") -> InputError | None:
        """check's verdict: the InputError naming the first moving window, or None (at rest)."""
        self._take(self.cut.flush())
        try:
            return self._verdict(quantum, where, name)
        finally:
            self.spill.close()

    def _verdict(self, quantum: float, where: str, name: str) -> InputError | None:
        n_quiet = sum(int(np.count_nonzero(p[:, 8] > 2)) for p in self.spill.pieces())
        if n_quiet == 0:  # moving_check: no noise reference, no verdict
            return None
        ref = float(
            np.linalg.norm(np.array([median(self.spill.column(j, _quiet), n_quiet) for j in (5, 6, 7)]))
        )
        med = np.array([median(self.spill.column(j), self.spill.n) for j in (2, 3, 4)])
        limit = max(MOVING_STD_FACTOR * ref, 4.0 * quantum)
        for p in self.spill.pieces():
            std, mean, n = np.ascontiguousarray(p[:, 5:8]), np.ascontiguousarray(p[:, 2:5]), p[:, 8]
            snorm = np.linalg.norm(std, axis=1)
            shift = np.linalg.norm(mean - med, axis=1)
            bad_std = (snorm > limit) & (n > 2)
            bad = bad_std | (shift > MOVING_MEAN_SHIFT_G)
            if bad.any():
                j = int(np.argmax(bad))
                return moving_error(
                    name, p[j, 0], p[j, 1], snorm[j] if bad_std[j] else None, shift[j], ref, where
                )
        return None


def _quiet(p: np.ndarray) -> np.ndarray:
    """The windows of > 2 samples (the noise reference's) of a piece of spilled rows."""
    return p[:, 8] > 2
