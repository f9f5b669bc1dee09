"""Per-sample driver signals of a session for models that read them (effects' `drivers`):
t_s (s), temp_degC, dtemp_degC_per_s (a centred local slope) and t_in_pose_s (s)."""

from __future__ import annotations

import numpy as np

from accellog.core.session import Session


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


def session_drivers(session: Session, needed: list[str] | None = None) -> dict[str, np.ndarray]:
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
