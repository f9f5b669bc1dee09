"""Per-sample driver signals of a session for models that read them (effects' `drivers`):
t_s (s), temp_degC, dtemp_degC_per_s (a centred local slope) and t_in_pose_s (s)."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Protocol

import numpy as np

from accellog.core.session import PoseLabel, Session

WHOLE_SERIES_DRIVERS = frozenset({"dtemp_degC_per_s"})
"""Drivers computed over a centred span of samples (a 5 s slope needs samples on both sides of a
block edge): a model reading one is applied to the whole session in memory."""


def needs_whole_series(drivers) -> bool:
    """Whether a model reading these drivers must see the whole series at once."""
    return not WHOLE_SERIES_DRIVERS.isdisjoint(drivers)


class BlockDrivers:
    """The driver signals of a session's consecutive blocks (a replay's batches): every pointwise
    driver computed on the block (the values session_drivers gives on the whole session), the
    WHOLE_SERIES_DRIVERS computed once on the whole session (which must then be given) and sliced."""

    def __init__(self, poses, session: Session | None = None) -> None:
        self.poses, self.session = poses, session
        self._whole: dict[str, np.ndarray] = {}

    def __call__(self, b, i0: int, needed) -> dict[str, np.ndarray]:
        """The needed drivers of block b (t_s, temp_degC), whose first sample is sample i0."""
        if not needed:
            return {}
        local = [k for k in needed if k not in WHOLE_SERIES_DRIVERS]
        view = SimpleNamespace(t_s=b.t_s, temp_degC=b.temp_degC, poses=self.poses)
        out = session_drivers(view, local) if local else {}
        whole = [k for k in needed if k in WHOLE_SERIES_DRIVERS]
        if whole:
            if self.session is None:
                raise ValueError(f"{whole} need the whole session in memory")
            missing = [k for k in whole if k not in self._whole]
            if missing:
                self._whole.update(session_drivers(self.session, missing))
            out.update({k: self._whole[k][i0 : i0 + b.n] for k in whole if k in self._whole})
        return out


def rate_of_change(t_s: np.ndarray, y: np.ndarray, span_s: float = 5.0) -> np.ndarray:
    """Local least-squares slope dy/dt over a centred window of span_s (unit of y per s), vectorised
    with cumulative sums; suits quantised signals such as TEMP_OUT."""
    t = np.asarray(t_s, float)
    y = np.asarray(y, float)
    n = t.size
    if n < 2:
        return np.zeros(n)
    lo = np.searchsorted(t, t - span_s / 2, side="left")
    hi = np.searchsorted(t, t + span_s / 2, side="right")
    tc = t - t.mean()
    yc = y - y.mean()

    def csum(x: np.ndarray) -> np.ndarray:
        return np.concatenate([[0.0], np.cumsum(x)])

    c1, ct, cy, ctt, cty = csum(np.ones(n)), csum(tc), csum(yc), csum(tc * tc), csum(tc * yc)
    k = c1[hi] - c1[lo]
    st, sy, stt, sty = ct[hi] - ct[lo], cy[hi] - cy[lo], ctt[hi] - ctt[lo], cty[hi] - cty[lo]
    den = k * stt - st * st
    with np.errstate(invalid="ignore", divide="ignore"):
        slope = np.where(den > 1e-12 * np.maximum(k * stt, 1e-300), (k * sty - st * sy) / den, 0.0)
    return slope


class Timeline(Protocol):
    """What the drivers are computed from: a Session, or a block of one with its session's labels."""

    @property
    def t_s(self) -> np.ndarray: ...  # (N,) s
    @property
    def temp_degC(self) -> np.ndarray | None: ...  # (N,) degC
    @property
    def poses(self) -> list[PoseLabel]: ...


def session_drivers(session: Timeline, needed: list[str] | None = None) -> dict[str, np.ndarray]:
    """Per-sample driver signals of a session: t_s, temp_degC, dtemp_degC_per_s (5 s local slope),
    t_in_pose_s (time since the start of the latest pose label at or before each sample; t_s when
    the session has no labels). Only `needed` drivers are computed when given."""
    want = set(needed) if needed is not None else {"t_s", "temp_degC", "dtemp_degC_per_s", "t_in_pose_s"}
    d: dict[str, np.ndarray] = {}
    t = session.t_s
    if "t_s" in want:
        d["t_s"] = t
    if session.temp_degC is not None:
        if "temp_degC" in want:
            d["temp_degC"] = session.temp_degC
        if "dtemp_degC_per_s" in want:
            d["dtemp_degC_per_s"] = rate_of_change(t, session.temp_degC)
    if "t_in_pose_s" in want:
        if session.poses:
            starts = np.sort(np.array([p.start_s for p in session.poses]))
            k = np.searchsorted(starts, t, side="right") - 1
            d["t_in_pose_s"] = np.where(k >= 0, t - starts[np.maximum(k, 0)], t)
        else:
            d["t_in_pose_s"] = t
    return d
