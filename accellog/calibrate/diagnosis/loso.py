"""Leave one session out: out-of-sample evidence from several calibration sessions of one sensor.

With K >= 2 sessions, a model is fitted on the windows of all sessions but k and scored on session
k, for every k in turn:

    score = sum_k chi2_k / sum_k m_k,   chi2_k = sum over session k's equations of (r / sigma)^2

(r: the labelled 3-axis residual, accellog.calibrate.diagnosis.transfer.heldout_score, or the gravity-norm
residual of hand-held sessions, the same with norm=True); per_part
holds each session's chi2 per equation. It is the held-out test with every session taking a turn,
so an effect that only stands in for another on one session's driver path does not win.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from accellog.calibrate.diagnosis.transfer import Score
from accellog.calibrate.model.compose import Model
from accellog.calibrate.model.fit import FitResult
from accellog.core.errors import ModelError
from accellog.core.session import ObsTable

KIND = "leave-one-session-out"

FitFn = Callable[[ObsTable, Model], FitResult]
ScoreFn = Callable[[FitResult, Sequence[ObsTable]], Score]


def _cat(parts: Sequence[ObsTable], name: str) -> np.ndarray | None:
    vals = [getattr(p, name) for p in parts]
    if any(v is None for v in vals):
        return None
    return np.concatenate([np.asarray(v, float) for v in vals])


def concat_obs(parts: Sequence[ObsTable]) -> ObsTable:
    """One ObsTable of several sessions' windows; pose ids are offset so every session's holds stay
    distinct (times and drivers stay per session: t_s is each session's own time)."""
    ids, names, off = [], [], 0
    for p in parts:
        ids.append(np.asarray(p.pose_id) + off)
        names += list(p.pose_names)
        off += len(p.pose_names)
    return ObsTable(
        meas_g=np.concatenate([p.meas_g for p in parts]),
        sigma_g=np.concatenate([p.sigma_g for p in parts]),
        up_sensor=np.concatenate([p.up_sensor for p in parts]),
        pose_id=np.concatenate(ids),
        pose_names=names,
        t_s=np.concatenate([p.t_s for p in parts]),
        t_in_pose_s=np.concatenate([p.t_in_pose_s for p in parts]),
        n_samples=np.concatenate([p.n_samples for p in parts]),
        std_g=np.concatenate([p.std_g for p in parts]),
        temp_degC=_cat(parts, "temp_degC"),
        dtemp_degC_per_s=_cat(parts, "dtemp_degC_per_s"),
        q_sensor_to_world=_cat(parts, "q_sensor_to_world"),
        session="+".join(p.session for p in parts if p.session),
    )


def fits_without(parts: Sequence[ObsTable], model: Model, fit: FitFn) -> list[FitResult | None]:
    """The model fitted on all sessions but k, for every k (None where that fit fails)."""
    out: list[FitResult | None] = []
    for k in range(len(parts)):
        try:
            out.append(fit(concat_obs([p for i, p in enumerate(parts) if i != k]), model))
        except ModelError:
            out.append(None)
    return out


def loso_score(parts: Sequence[ObsTable], model: Model, fit: FitFn, score: ScoreFn) -> Score:
    """Leave-one-session-out chi2 per equation of `model` (module doc); inf where a fit fails."""
    chi2, m = 0.0, 0
    per: list[float] = []
    for k, res in enumerate(fits_without(parts, model, fit)):
        if res is None:
            chi2, per = np.inf, [*per, np.inf]
            m += 3 * parts[k].n
            continue
        s = score(res, [parts[k]])
        chi2 += s.chi2_per_eq * s.n_eq
        m += s.n_eq
        per.append(s.chi2_per_eq)
    return Score(KIND, chi2 / max(m, 1), m, per)


def loso_stats(
    parts: Sequence[ObsTable],
    model: Model,
    fit: FitFn,
    stats: Callable[[FitResult, ObsTable], dict[str, float]],
) -> list[dict[str, float] | None]:
    """Per session k: held-out statistics (heldout_rms_g, heldout_noise_g, heldout_chi2_dof) of the
    model fitted on the other sessions (None where that fit fails)."""
    return [
        None if res is None else stats(res, parts[k]) for k, res in enumerate(fits_without(parts, model, fit))
    ]


def mean_stats(per_session: Sequence[dict[str, float] | None]) -> dict[str, float]:
    """Mean of per-session statistics (inf when a session could not be predicted)."""
    keys: tuple[str, ...] = ("heldout_rms_g", "heldout_noise_g", "heldout_chi2_dof")
    if all(s is not None and "heldout_chi2_dof_noise" in s for s in per_session):
        keys += ("heldout_chi2_dof_noise",)
    known = [s for s in per_session if s is not None]
    if len(known) < len(per_session):
        return dict.fromkeys(keys, float("inf"))
    return {k: float(np.mean([s[k] for s in known])) for k in keys}
