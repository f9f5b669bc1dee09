"""Stage 'segment' of a session in memory: static holds -> observation tables and statistics for fitting.

``observations`` and ``pose_stats`` take a Session, a file or a ``store.source.Source`` and hand its
one pass (a file chunk by chunk, a Session checked and as a single block) to the one implementation
of the stage, ``stream_segment.segment_blocks``: each labelled hold
[start_s, end_s) is trimmed by trim_s at both ends (the hand that turned the cube is still
settling) and cut into windows of about window_s; each window gives one observation

    meas_g = window mean (g),   sigma_g = std_window * sqrt(tau_hold / n_window)   (g)

where tau_hold is the hold's integrated autocorrelation time (samples, ``hold_noise``). Several
windows per hold keep slow effects (temperature, warm-up, time drift) visible to the fit.

Checks (each raises InputError naming the pose and time): no labels, overlapping or duplicated
labels, too few samples, NaN readings, a reading far from 1 g at rest (wrong units, e.g. counts
declared as g), a label far from the measured gravity, and a hold labelled static that moves
(window variance far above the noise, or a window mean that wanders from the hold's median by more
than a few degrees). Pose tables (the seed's summaries) give observations by ``obs_from_pose_means``.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from accellog.calibrate.observe.holds import (
    MIN_WINDOW_SAMPLES,
    UNIT_NORM_RANGE_G,
    PoseStats,
    check_window,
    checked_labels,
    quantum_g,
    session_where,
    window_stats,
)
from accellog.calibrate.observe.motion import (
    MOVING_MEAN_SHIFT_G,
    MOVING_STD_FACTOR,
    check_static,
    mean_shift,
    moving_check,
    moving_error,
    moving_verdict,
    static_windows,
)
from accellog.calibrate.observe.stream_segment import segment_blocks
from accellog.core.errors import InputError, ModelError
from accellog.core.session import POSE_UP_VECTORS, ObsTable, Session
from accellog.store.source import Source, check_timestamps, open_source
from accellog.store.stream import closed_after

__all__ = [  # the stage's names, wherever they live (callers import them from here)
    "MIN_WINDOW_SAMPLES", "MOVING_MEAN_SHIFT_G", "MOVING_STD_FACTOR", "UNIT_NORM_RANGE_G", "PoseStats",
    "check_coverage", "check_static", "check_window", "checked_labels", "mean_shift", "moving_check",
    "moving_error", "moving_verdict", "obs_from_pose_means", "observations", "pose_name_for_up",
    "pose_stats", "quantum_g", "session_where", "static_windows", "window_stats",
]  # fmt: skip


def pose_name_for_up(up: np.ndarray) -> str:
    """'+z' etc. for an up vector along an axis, else 'up(x,y,z)'."""
    for name, vec in POSE_UP_VECTORS.items():
        if np.allclose(up, vec, atol=1e-9):
            return name
    return "up(" + ",".join(f"{v:.3f}" for v in up) + ")"


def _segment(data, window_s: float | None, trim_s: float, stats_out: list | None, on_block, **checks):
    """segment_blocks over one Source.run pass (module doc); a Session's samples checked first."""
    src = open_source(data, what="segment")
    if window_s is not None:
        check_window(window_s, src.meta.sample_rate_hz, src.where)

    def one_pass(s: Source) -> ObsTable | None:
        if stats_out is not None:
            stats_out.clear()  # a pass run again (a damaged file read whole) starts afresh
        whole = s.session is not None  # in memory
        if s.session is not None:
            name = s.session.path or s.meta.source
            if s.session.n == 0 and s.poses:
                raise InputError("session has no samples", where=s.where)
            check_timestamps(s.session, where=s.where)
        with closed_after(s.blocks()) as blocks:
            return segment_blocks(s.meta, s.poses, blocks, window_s, trim_s, where=s.where,
                                  name=name if whole else None, events=s.events, stats_out=stats_out,
                                  on_block=on_block, release=not whole, threaded=not whole, **checks)  # fmt: skip

    return src.run(one_pass)


def pose_stats(
    data: Session | Source | str | os.PathLike,
    *,
    trim_s: float = 0.5,
    min_samples: int = 20,
    check_units: bool = True,
    check_moving: bool = True,
) -> list[PoseStats]:
    """Per-hold statistics (mean, std, autocorrelation-aware sem, tau, temperature, times)."""
    out: list[PoseStats] = []
    _segment(data, None, trim_s, out, None, min_samples=min_samples, check_units=check_units,
             check_moving=check_moving)  # fmt: skip
    return out


def observations(
    data: Session | Source | str | os.PathLike,
    window_s: float = 2.0,
    trim_s: float = 0.5,
    *,
    min_samples: int = 20,
    check_units: bool = True,
    check_moving: bool = True,
    stats_out: list[PoseStats] | None = None,
    on_block: Callable | None = None,
) -> ObsTable:
    """ObsTable with one row per window of about window_s in every trimmed hold (holds.hold_rows:
    meas_g = window mean, sigma_g = std_window sqrt(tau_hold / n_window), t_s = mean sample time
    of the window, temperature and its slope, the label's nominal orientation) of a session in
    memory or a file (store.source: chunk by chunk). stats_out receives every hold's PoseStats;
    on_block(block) sees every block of the pass (it sees a pass again when a damaged file is
    read whole: it must start afresh at the first block)."""
    return _segment(data, window_s, trim_s, stats_out, on_block, min_samples=min_samples,
                    check_units=check_units, check_moving=check_moving)  # fmt: skip


def observe_riding(
    src: Source, *, window_s: float = 2.0, trim_s: float = 0.5, rider: Callable | None = None
) -> tuple[ObsTable, Any, Source]:
    """(observations, the rider, src) of one pass: rider(src), made afresh at each pass, is fed every
    block (add(block)) along the observation pass, e.g. the gyro calibration's first pass or the host
    clock points; a rider that fails is dropped (None: its owner then makes its own pass and says
    why). src is returned: from a forked child (core.forked) it is the one that read the file (read
    whole there when its chunks were damaged)."""

    def one_pass(s: Source):
        box = [rider(s) if rider is not None else None]

        def ride(b) -> None:
            if box[0] is not None:
                try:
                    box[0].add(b)
                except Exception:
                    box[0] = None

        return observations(s, window_s=window_s, trim_s=trim_s, on_block=ride), box[0]

    table, fed = src.run(one_pass)
    return table, fed, src


def obs_from_pose_means(
    up: np.ndarray,
    mean_g: np.ndarray,
    std_g: np.ndarray,
    n: int | np.ndarray,
    *,
    names: Sequence[str] | None = None,
    session: str = "",
    where: str | None = None,
) -> ObsTable:
    """ObsTable with one row per pose from summary means (the seed's six_position_data CSVs).

    up: (k,3) true reading / 1 g (the seed's x_true, y_true, z_true columns), mean_g, std_g: (k,3);
    n: samples per pose (scalar or (k,)). sigma_g = std_g / sqrt(n): the summaries carry no
    autocorrelation information, so this naive standard error is too small (documented limit).
    """
    up = np.atleast_2d(np.asarray(up, float))
    mean_g = np.atleast_2d(np.asarray(mean_g, float))
    std_g = np.atleast_2d(np.asarray(std_g, float))
    k = up.shape[0]
    if up.shape != (k, 3) or mean_g.shape != (k, 3) or std_g.shape != (k, 3):
        raise InputError(
            f"pose table shapes differ: up {up.shape}, mean {mean_g.shape}, std {std_g.shape}", where=where
        )
    for arr, what in ((up, "truth"), (mean_g, "mean"), (std_g, "std")):
        if not np.isfinite(arr).all():
            row = int(np.argmax(~np.isfinite(arr).all(axis=1)))
            raise InputError(f"{what} of pose row {row + 1} is NaN", where=where)
    nn = np.broadcast_to(np.asarray(n, float), (k,)).astype(float)
    pose_names = list(names) if names is not None else [pose_name_for_up(u) for u in up]
    dup = {x for x in pose_names if pose_names.count(x) > 1}
    if dup:
        raise InputError(f"pose(s) {sorted(dup)} appear more than once in the pose table", where=where)
    return ObsTable(
        meas_g=mean_g.copy(),
        sigma_g=std_g / np.sqrt(nn)[:, None],
        up_sensor=up.copy(),
        pose_id=np.arange(k),
        pose_names=pose_names,
        t_s=np.zeros(k),
        t_in_pose_s=np.zeros(k),
        n_samples=nn.astype(int),
        std_g=std_g.copy(),
        q_sensor_to_world=np.full((k, 4), np.nan),
        session=session,
    )


NEAR_ONE_DIRECTION_DEG = 30.0
"""Holds whose up vectors all lie within this of their mean direction are a robot's stops near level
(fitted as stops when they cannot separate bias from scale), not a lab session missing faces."""


def near_one_direction(obs: ObsTable, deg: float = NEAR_ONE_DIRECTION_DEG) -> bool:
    """Do the windows' up vectors all lie within deg of their mean direction (False without windows)?"""
    if obs.n == 0:
        return False
    ups = np.asarray(obs.up_sensor, float)
    mean = ups.mean(axis=0)
    norm = float(np.linalg.norm(mean))
    return norm > 0 and bool(np.min(ups @ (mean / norm)) >= np.cos(np.radians(deg)))


def check_coverage(obs: ObsTable, needs_scale: bool = True, where: str | None = None) -> None:
    """Raise ModelError if the poses cannot determine the model.

    Bias-only needs one pose; a scale or 3x3 model needs up vectors that are affinely independent in
    3-D (rank [up 1] = 4), e.g. both sides of every axis. The message lists the missing faces.
    """
    if obs.n == 0:
        raise ModelError("no observations to fit", where=where or obs.session or None)
    if not needs_scale:
        return
    ups = np.unique(np.round(obs.up_sensor, 6), axis=0)
    A = np.c_[ups, np.ones(ups.shape[0])]
    # Per axis i, bias and scale separate only with two different up_i values.
    spread = np.ptp(ups, axis=0) if ups.shape[0] else np.zeros(3)
    if np.linalg.matrix_rank(A) < 4 or np.any(spread < 0.5):
        have = {pose_name_for_up(u) for u in ups}
        near = ups @ np.array(list(POSE_UP_VECTORS.values())).T > np.cos(np.radians(30.0))  # within 30 deg
        missing = [
            f for f, hit in zip(POSE_UP_VECTORS, near.any(axis=0), strict=True) if not hit and f not in have
        ]
        named = (
            f"poses {sorted(have)}" if len(have) <= 8 else f"{len(have)} poses"
        )  # a robot's stops: counted
        span = ", ".join(
            f"{a} {lo:+.2f}..{hi:+.2f}" for a, lo, hi in zip("xyz", ups.min(0), ups.max(0), strict=True)
        )
        raise ModelError(
            f"{named} cannot separate bias from scale (up vectors span {span}; each axis needs two holds "
            f"0.5 g apart): missing {', '.join(missing) or 'distinct poses'}",
            where=where or obs.session or None,
        )
