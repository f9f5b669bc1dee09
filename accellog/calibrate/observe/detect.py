"""Automatic static detection: holds found in an unlabelled (hand-held) session.

A sample is still where the moving variance of |a| over a window is below a threshold chosen from the
session's own noise; runs of still samples longer than the minimum hold become holds labelled by the
nearest face (or 'auto' where the direction is not a face).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence

import numpy as np

from accellog.calibrate.observe.segment import quantum_g, session_where
from accellog.core.errors import InputError
from accellog.core.session import PoseLabel, Session, vec3
from accellog.core.timeseries import runs

# ---------------------------------------------------------------- automatic static detection


def _moving_var_norm(x: np.ndarray, w: int) -> np.ndarray:
    """||var over a centred window of w samples||_2 (per-axis variances), inf at the edges."""
    n = x.shape[0]
    out = np.full(n, np.inf)
    if n < w:
        return out
    xc = x - x.mean(axis=0)
    c1 = np.concatenate([np.zeros((1, 3)), np.cumsum(xc, axis=0)])
    c2 = np.concatenate([np.zeros((1, 3)), np.cumsum(xc * xc, axis=0)])
    s1 = c1[w:] - c1[:-w]
    s2 = c2[w:] - c2[:-w]
    var = np.maximum(s2 / w - (s1 / w) ** 2, 0.0)
    h = w // 2
    out[h : h + var.shape[0]] = np.linalg.norm(var, axis=1)
    return out


def _distinct(dirs: np.ndarray, angle_deg: float) -> int:
    """Number of distinct directions (greedy clustering by angle)."""
    reps: list[np.ndarray] = []
    cos_lim = np.cos(np.deg2rad(angle_deg))
    for d in dirs:  # a few dozen intervals at most
        if not reps or np.max(np.asarray(reps) @ d) < cos_lim:
            reps.append(d)
    return len(reps)


class TooFewOrientations(InputError):
    """An unlabelled session whose still intervals point in too few directions for a full
    orientation-free fit (`fit` then fits only what its stops identify: flows.stages.run_fit)."""


def detect_static(
    session: Session,
    *,
    window_samples: int = 101,
    init_static_s: float | None = None,
    k_values: Sequence[float] = tuple(range(2, 11)),
    min_interval_s: float = 1.0,
    min_poses: int = 9,
    distinct_angle_deg: float = 10.0,
    cost: Callable[[list[PoseLabel]], float] | None = None,
) -> list[PoseLabel]:
    """Static intervals of unlabelled data as PoseLabels (imu_tk's detector with a threshold sweep).

    Statistic: s = ||per-axis variance over a centred window of window_samples||. Reference
    r = ||per-axis variance of the first init_static_s seconds|| (the recording starts still), or,
    when None, the 5th percentile of s. For each k in k_values the intervals with s < k r lasting
    >= min_interval_s are candidates; with `cost` (e.g. an orientation-free fit's residual) the k
    with the lowest cost is kept (as imu_tk), otherwise the k giving the most distinct poses, then
    the fewest intervals (ties: the smallest k). The fewest: s of a still stretch fluctuates (a
    w-sample variance has a relative spread ~sqrt(2 / w)), so a tight k cuts one hold into pieces
    wherever s crosses k r (a still 60 s test at 1 kHz: 8 pieces at k = 2, one at k = 3). up_sensor of each label = its mean reading normalised (an estimate, not truth).
    Raises InputError when fewer than min_poses distinct orientations (> distinct_angle_deg apart)
    are found.
    """
    where = session_where(session)
    acc = session.accel_g
    t = session.t_s
    if session.n < window_samples:
        raise InputError(
            f"{session.n} samples are too few for static detection (window {window_samples})", where=where
        )
    if not np.isfinite(acc).all():
        i = int(np.argmax(~np.isfinite(acc).all(axis=1)))
        raise InputError(f"accel is NaN/inf at t = {t[i]:.3f} s", where=where)
    labels, max_found = static_sweep(
        session, window_samples=window_samples, init_static_s=init_static_s, k_values=k_values,
        min_interval_s=min_interval_s, min_poses=min_poses, distinct_angle_deg=distinct_angle_deg, cost=cost,
    )  # fmt: skip
    if labels is None:
        cut = any(e.kind == "recovered" for e in session.events)
        raise TooFewOrientations(
            f"found at most {max_found} distinct static orientations (need >= {min_poses} for an "
            f"orientation-free fit): {_labelling_hint(session, max_found, min_poses, min_interval_s)}"
            + ("; the file is truncated: any pose labels went with its end" if cut else ""),
            where=where,
        )
    return labels


def static_sweep(
    session: Session,
    *,
    window_samples: int = 101,
    init_static_s: float | None = None,
    k_values: Sequence[float] = tuple(range(2, 11)),
    min_interval_s: float = 1.0,
    min_poses: int = 9,
    distinct_angle_deg: float = 10.0,
    cost: Callable[[list[PoseLabel]], float] | None = None,
) -> tuple[list[PoseLabel] | None, int]:
    """detect_static's threshold sweep on >= window_samples finite samples: (the chosen labels, or
    None when fewer than min_poses distinct orientations; the most distinct orientations found)."""
    acc = session.accel_g
    t = session.t_s
    stat = _moving_var_norm(acc, window_samples)
    if init_static_s is not None:
        sl = session.slice_time(t[0], t[0] + init_static_s)
        ref = float(np.linalg.norm(acc[sl].var(axis=0)))
    else:
        ref = float(np.percentile(stat[np.isfinite(stat)], 5))
    ref = max(ref, (quantum_g(session) ** 2) / 12.0, 1e-15)
    rate = (session.n - 1) / max(t[-1] - t[0], 1e-12)
    min_len = max(int(np.ceil(min_interval_s * rate)), 2)
    best: tuple[tuple[float, int], list[PoseLabel], int] | None = None
    max_found = 0
    csum = np.concatenate([np.zeros((1, 3)), np.cumsum(acc, axis=0)])
    # label [start_s, end_s) covers samples a..b-1: end at the next sample's time (one period past the end)
    t_end = np.append(t[1:], t[-1] + 1.0 / rate)
    for k in k_values:
        starts, stops = runs(stat < k * ref).T
        keep = (stops - starts) >= min_len
        starts, stops = starts[keep], stops[keep]
        if starts.size == 0:
            continue
        means = (csum[stops] - csum[starts]) / (stops - starts)[:, None]
        norms = np.linalg.norm(means, axis=1)
        dirs = means / np.maximum(norms, 1e-12)[:, None]
        nd = _distinct(dirs, distinct_angle_deg)
        max_found = max(max_found, nd)
        if nd < min_poses:
            continue
        labels = [
            PoseLabel(
                name=f"static{j:02d}",
                start_s=float(t[a]),
                end_s=float(t_end[b - 1]),
                up_sensor=vec3(dirs[j]),
                hold_index=j,
            )
            for j, (a, b) in enumerate(zip(starts, stops, strict=True))
        ]
        score = (float(cost(labels)), 0) if cost is not None else (-float(nd), len(labels))
        if best is None or score < best[0]:
            best = (score, labels, nd)
    return (None if best is None else best[1]), max_found


_TABLE_FACES = 6
"""A table protocol's distinct orientations (six faces; rotations about the vertical look alike)."""


def _labelling_hint(session: Session, found: int, need: int, min_interval_s: float) -> str:
    """The one thing that makes an unlabelled session fit: labels from the importer (a table protocol:
    the six faces found) or still holds in more orientations."""
    more = f"hold the sensor still for >= {min_interval_s:g} s in more orientations"
    source = session.meta.source
    kind = source.split(":", 1)[1] if source.startswith("import:") else ""
    if found < _TABLE_FACES or need <= _TABLE_FACES or kind not in ("csv", "ros2"):
        return more
    pose = "give the file a pose column, or " if kind == "csv" else ""
    return (
        f"the holds look like a table protocol (rotations about the vertical read as one orientation): "
        f"{pose}re-import it with `accellog import {kind} ... --detect-holds` to label them as faces"
    )


def with_labels(session: Session, labels: list[PoseLabel]) -> Session:
    """A shallow copy of session with its pose labels replaced."""
    return dataclasses.replace(session, poses=list(labels))
