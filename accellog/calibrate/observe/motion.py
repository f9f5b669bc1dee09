"""The motion check: does a hold labelled static move? (accelerations in g)

Each hold is cut into window_s (0.5 s) windows (``static_windows``); the noise reference is the
norm of the median window std per axis over the whole session (most windows are static). A window
moves if its std norm exceeds MOVING_STD_FACTOR x the reference (and 4 quanta), or its mean leaves
the hold's median window mean by more than MOVING_MEAN_SHIFT_G (~3 deg). The first moving window
is named with its pose and time (``moving_error``).

``MotionCheck`` gives the same verdict, window and message for one hold fed block by block (a static
test of any length) in bounded memory: each block's windows (start s, end s, mean g (3), std g (3),
count) are spilled to a temporary file (72 bytes a window, in the page cache; ``window_spill``) and
the two session medians (window std per axis over windows of > 2 samples; window mean per axis) are
found exactly by its radix selection (np.median: the middle value, or the mean of the two).
"""

from __future__ import annotations

import numpy as np

from accellog.calibrate.observe.holds import WindowSums, quantum_g, session_where, window_edges, window_stats
from accellog.calibrate.observe.window_spill import WindowSpill, median
from accellog.core.errors import InputError
from accellog.core.session import PoseLabel, Session
from accellog.core.timeseries import WindowCarry

MOVING_STD_FACTOR = 6.0
"""A check window whose std (norm over axes) exceeds this multiple of the session noise moves."""
MOVING_MEAN_SHIFT_G = 0.05
"""A check window whose mean leaves the hold's median by more than this (g, ~3 deg) moves."""


def check_static(
    session: Session,
    holds: list[tuple[PoseLabel, slice]],
    *,
    window_s: float = 0.5,
    std_factor: float = MOVING_STD_FACTOR,
    mean_shift_g: float = MOVING_MEAN_SHIFT_G,
) -> None:
    """Raise InputError if a hold (label, sample slice of session) labelled static moves (module doc)."""
    per_hold = [(p, *static_windows(session.t_s[sl], session.accel_g[sl], window_s)) for p, sl in holds]
    moving_check(per_hold, quantum_g(session), session_where(session), std_factor, mean_shift_g)


def static_windows(
    t: np.ndarray, acc: np.ndarray, window_s: float = 0.5, mean: np.ndarray | None = None
) -> tuple:
    """check_static's windows of one hold: (window start times, end times, mean, std, n); mean:
    acc.mean(axis=0) when the caller has it (the same values, not computed again)."""
    mean = acc.mean(axis=0) if mean is None else mean
    sums = WindowSums(window_edges(float(t[0]), float(t[-1]), window_s), float(t[0]), False)
    xc = acc - mean
    sums.add(t, xc, xc * xc, None)
    return sums.stats(mean)[:5]


def moving_check(
    per_hold: list[tuple],
    quantum: float,
    where: str,
    std_factor: float = MOVING_STD_FACTOR,
    mean_shift_g: float = MOVING_MEAN_SHIFT_G,
) -> None:
    """check_static's verdict from every hold's static_windows (label first): the noise reference
    is the median window std over the whole session."""
    shifted = [(p, t0, t1, mean_shift(mean), std, n) for p, t0, t1, mean, std, n in per_hold]
    refusal = moving_verdict(shifted, quantum, where, std_factor, mean_shift_g)
    if refusal is not None:
        raise refusal


def mean_shift(mean: np.ndarray) -> np.ndarray:
    """|window mean - the hold's median window mean| (g) per window of one hold."""
    return np.linalg.norm(mean - np.median(mean, axis=0), axis=1)


def moving_verdict(
    per_hold: list[tuple],
    quantum: float,
    where: str,
    std_factor: float = MOVING_STD_FACTOR,
    mean_shift_g: float = MOVING_MEAN_SHIFT_G,
    ref: float | None = None,
) -> InputError | None:
    """moving_check's refusal (the InputError naming the first moving window) or None, on (label,
    t_start, t_end, mean_shift, std, n) per hold (the shift taken when the hold passed: no window
    means kept); ref: the session noise reference (g, the norm of the median
    std per axis of the windows of n > 2) when the caller has it (then there is such a window)."""
    if ref is None:
        all_std = np.concatenate([h[4][h[5] > 2] for h in per_hold]) if per_hold else np.zeros((0, 3))
        if all_std.shape[0] == 0:
            return None
        ref = float(np.linalg.norm(np.median(all_std, axis=0)))
    limit = max(std_factor * ref, 4.0 * quantum)
    for p, t_start, t_end, shift, std, n in per_hold:
        snorm = np.linalg.norm(std, axis=1)
        bad_std = (snorm > limit) & (n > 2)
        bad_mean = shift > mean_shift_g
        bad = bad_std | bad_mean
        if bad.any():
            j = int(np.argmax(bad))
            return moving_error(
                p.name, t_start[j], t_end[j], snorm[j] if bad_std[j] else None, shift[j], ref, where
            )
    return None


def moving_error(
    name: str, t_start: float, t_end: float, std_g: float | None, shift_g: float, ref: float, where: str
) -> InputError:
    """The motion check's refusal of the window t_start..t_end (s) of hold ``name``: its std norm
    std_g (g) against the session noise ref (g), or (std_g None) its mean shift_g (g)."""
    why = (
        f"accel std {std_g:.4g} g is {std_g / max(ref, 1e-12):.0f}x the session noise {ref:.3g} g"
        if std_g is not None
        else f"mean moved {shift_g:.3g} g from the hold's median"
    )
    return InputError(
        f"pose {name!r} is labelled static but moves at t = {t_start:.2f}-{t_end:.2f} s: "
        f"{why}; relabel or trim the hold",
        where=where,
    )


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
        hold = PoseLabel(name=name, start_s=0.0, end_s=0.0, up_sensor=(0.0, 0.0, 1.0))
        for p in self.spill.pieces():  # each piece as a hold of its own, against the whole hold's medians
            shift = np.linalg.norm(np.ascontiguousarray(p[:, 2:5]) - med, axis=1)
            std = np.ascontiguousarray(p[:, 5:8])
            refusal = moving_verdict([(hold, p[:, 0], p[:, 1], shift, std, p[:, 8])], quantum, where, ref=ref)
            if refusal is not None:
                return refusal
        return None


def _quiet(p: np.ndarray) -> np.ndarray:
    """The windows of > 2 samples (the noise reference's) of a piece of spilled rows."""
    return p[:, 8] > 2
