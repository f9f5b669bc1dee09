"""The motion check: does a hold labelled static move? (accelerations in g)

Each hold is cut into window_s (0.5 s) windows (``static_windows``); the noise reference is the
norm of the median window std per axis over the whole session (most windows are static). A window
moves if its std norm exceeds MOVING_STD_FACTOR x the reference (and 4 quanta), or its mean leaves
the hold's median window mean by more than MOVING_MEAN_SHIFT_G (~3 deg). The first moving window
is named with its pose and time (``moving_error``).
"""

from __future__ import annotations

import numpy as np

from accellog.calibrate.observe.holds import quantum_g, session_where, window_stats
from accellog.core.errors import InputError
from accellog.core.session import PoseLabel, Session

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
    edges = np.arange(t[0], t[-1], window_s)
    starts = np.unique(np.searchsorted(t, edges))
    mean, std, n = window_stats(acc, starts, mean)
    ends = np.append(starts[1:] - 1, t.shape[0] - 1)
    return t[starts], t[ends], mean, std, n


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
    moving_verdict(shifted, quantum, where, std_factor, mean_shift_g)


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
) -> None:
    """moving_check on (label, t_start, t_end, mean_shift, std, n) per hold (the shift taken when the
    hold passed: no window means kept); ref: the session noise reference (g, the norm of the median
    std per axis of the windows of n > 2) when the caller has it (then there is such a window)."""
    if ref is None:
        all_std = np.concatenate([h[4][h[5] > 2] for h in per_hold]) if per_hold else np.zeros((0, 3))
        if all_std.shape[0] == 0:
            return
        ref = float(np.linalg.norm(np.median(all_std, axis=0)))
    limit = max(std_factor * ref, 4.0 * quantum)
    for p, t_start, t_end, shift, std, n in per_hold:
        snorm = np.linalg.norm(std, axis=1)
        bad_std = (snorm > limit) & (n > 2)
        bad_mean = shift > mean_shift_g
        bad = bad_std | bad_mean
        if bad.any():
            j = int(np.argmax(bad))
            raise moving_error(
                p.name, t_start[j], t_end[j], snorm[j] if bad_std[j] else None, shift[j], ref, where
            )


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
