"""Hand-held sessions (no pose labels): diagnose on automatically detected static intervals.

Without orientations only the gravity norm is observed (imu_tk / ArduPilot): per window

    e_r = |S^-1 (a'_r - b(drivers)) ...| - g          (model.correct, then the norm)

and chi2 = sum (e_r / sigma_n,r)^2 with sigma_n the window noise projected on the measured
direction. Candidates are fitted with `fit_orientation_free` and judged like diagnose's (F test,
dBIC; p < alpha / n and dBIC < -10). What the norm cannot see is said, not guessed: a rotation of
the sensor frame (3 of the 6 cross_axis terms, so misalignment_tri replaces it), the fixture tilt
and the sample clock.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats

from accellog.calibrate.diagnosis.diagnose import (
    ALPHA,
    DBIC_MIN,
    Diagnosis,
    default_candidates,
    rank_rows,
    with_choice,
)
from accellog.calibrate.model.compose import Model
from accellog.calibrate.model.effects import all_effects
from accellog.calibrate.model.fit import fit_orientation_free, obs_drivers
from accellog.calibrate.model.identifiability import effect_requirement, norm_blind_reason
from accellog.calibrate.observe.detect import detect_static, with_labels
from accellog.calibrate.observe.segment import observations
from accellog.core.errors import InputError, ModelError
from accellog.core.session import ObsTable, Session

HANDHELD_START = "bias+scale+misalignment_tri"
"""The start model of a hand-held session (orientation-free: a frame rotation is unobservable)."""
NORM_BLIND = {
    "cross_axis": "3 of its 6 terms are a rotation of the sensor frame, invisible in |f|: use "
    "misalignment_tri (the other 3), or record labelled poses",
    "fixture_tilt": "needs pose labels (the tilt of a fixture is a rotation of every truth)",
    "clock": "a sample-clock error does not change static readings: supply host timestamps",
}
"""Effects the gravity norm cannot identify, with what to do instead."""


@dataclass
class Detection:
    """Static intervals found by the detector and the settings that found them."""

    intervals: list[dict]
    window_s: float
    threshold: float | None
    """Fixed threshold factor k (statistic < k * reference), or None: swept 2..10, best by the
    orientation-free residual."""

    def to_dict(self) -> dict:
        return {"window_s": self.window_s, "threshold": self.threshold, "intervals": self.intervals}


def detect_holds(
    session: Session,
    *,
    window_s: float = 1.0,
    threshold: float | None = None,
    obs_window_s: float = 2.0,
    model: str = HANDHELD_START,
) -> tuple[ObsTable, Detection]:
    """Detect the static intervals of an unlabelled session (variance window `window_s` s,
    threshold factor `threshold` or a sweep scored by the orientation-free fit) and cut them into
    observation windows."""
    from accellog.calibrate.model.compose import build_model

    if not window_s > 0:
        raise InputError(f"detector window must be > 0 s, got {window_s}")
    rate = (session.n - 1) / max(float(session.t_s[-1] - session.t_s[0]), 1e-12)
    w = max(3, round(window_s * rate) | 1)
    m = build_model(model)

    def cost(labels) -> float:
        o = observations(with_labels(session, labels), window_s=obs_window_s, trim_s=0.0, check_units=False)
        try:
            return fit_orientation_free(o, m, weighted=False).rms_g
        except ModelError:
            return np.inf

    ks = (float(threshold),) if threshold is not None else tuple(range(2, 11))
    labels = detect_static(session, window_samples=w, k_values=ks, cost=cost)
    obs = observations(with_labels(session, labels), window_s=obs_window_s, trim_s=0.0)
    iv = [
        {
            "start_s": p.start_s,
            "end_s": p.end_s,
            "n": int(np.sum((session.t_s >= p.start_s) & (session.t_s < p.end_s))),
            "up_sensor": [float(x) for x in p.up_sensor],
        }
        for p in labels
    ]
    return obs, Detection(iv, float(window_s), threshold)


def diagnose_handheld(obs: ObsTable, model: Model, *, candidates: Sequence[str] | None = None) -> Diagnosis:
    """diagnose() for unlabelled holds: the orientation-free fit against the noise, then every
    library effect the norm can identify as a candidate (model + effect)."""
    drv = obs_drivers(obs)
    base = fit_orientation_free(obs, model)
    lib = all_effects(model.effects_file)
    cands = list(candidates) if candidates is not None else default_candidates(model)
    n_tests = max(1, len(cands))
    rows, fits = [], {}
    for name in cands:
        row: dict = {"effect": name, "n_params": len(lib[name].params), "identifiable": False}
        rows.append(row)
        why = (
            NORM_BLIND.get(name)
            or norm_blind_reason(model, name)
            or effect_requirement(name, obs, drv, model)
        )
        if why is None:
            try:
                cr = fit_orientation_free(obs, model.with_terms([name]))
            except ModelError as exc:
                why = str(exc)
        if why is not None:
            row["reason"] = why
            continue
        fits[name] = cr
        row.update(_norm_candidate_stats(name, cr, model, base, n_tests, obs.n))
    rows.sort(
        key=lambda r: (not r.get("significant", False), not r["identifiable"], r.get("delta_bic", np.inf))
    )
    for k, r in enumerate(rows, 1):
        r["rank"] = k
    sig = [r for r in rows if r.get("significant")]
    floor = float(np.sqrt(np.mean(np.asarray(obs.sigma_g, float) ** 2)))
    base_bad = bool(np.isfinite(base.p_value) and base.p_value < ALPHA and base.dof > 0)
    missing = base_bad or bool(sig)
    verdict, advice = _handheld_verdict(obs, model, base, rows, sig, missing)
    return Diagnosis(
        model=model,
        fit=base,
        noise_floor_g=floor,
        missing=missing,
        verdict=verdict,
        candidates=rows,
        driver_signals=[],
        advice=advice,
        best=sig[0]["effect"] if sig else None,
        fits=fits,
    )


def _norm_candidate_stats(name: str, cr, model: Model, base, n_tests: int, m_eq: int) -> dict:
    """F test and dBIC of the norm fit cr (model + name) against base (m_eq = rows)."""
    dk = cr.model.n_params - model.n_params
    dchi2 = base.chi2 - cr.chi2
    F = (dchi2 / max(dk, 1)) / max(cr.chi2 / max(cr.dof, 1), 1e-300)
    p = float(stats.f.sf(F, max(dk, 1), max(cr.dof, 1))) if cr.dof > 0 else np.nan
    dbic = float(-dchi2 + dk * np.log(m_eq))
    sl = cr.model.slices[name]
    return dict(
        identifiable=True,
        significant=bool(cr.dof > 0 and p < ALPHA / n_tests and dbic < DBIC_MIN),
        chi2_dof=cr.chi2_dof,
        delta_chi2=dchi2,
        delta_chi2_dof=base.chi2_dof - cr.chi2_dof,
        F=F,
        p_value=p,
        delta_bic=dbic,
        params={
            n: [float(v), float(s)]
            for n, v, s in zip(cr.model.param_names[sl], cr.theta[sl], cr.sigma[sl], strict=True)
        },
        reason=f"norm chi2/dof {base.chi2_dof:.3g} -> {cr.chi2_dof:.3g}, dBIC {dbic:.1f}",
    )


def _handheld_verdict(obs: ObsTable, model: Model, base, rows, sig, missing: bool) -> tuple[str, list[str]]:
    """Verdict line and advice of diagnose_handheld (what the norm cannot show, listed too)."""
    head = (
        f"{model.name} (orientation-free, {obs.n} windows in {len(np.unique(obs.pose_id))} detected holds): "
        f"norm chi2/dof = {base.chi2_dof:.3g}"
    )
    advice = [f"{r['effect']}: {r['reason']}" for r in rows if not r["identifiable"]]
    listed = {r["effect"] for r in rows}
    advice += [
        f"{e}: cannot be identified without orientations: {why}"
        for e, why in NORM_BLIND.items()
        if e not in listed and e not in model.term_names
    ]
    if sig:
        verdict = f"{head}: something is missing. Most likely: {sig[0]['effect']} ({sig[0]['reason']})."
        advice.insert(0, f"refit with --add {sig[0]['effect']}")
    elif missing:
        verdict = f"{head}: residuals exceed the noise, but no effect the norm can identify explains them."
    else:
        verdict = f"{head}: the model fits to the noise floor of the gravity norm; nothing is missing that the norm can show."
    return verdict, advice


def norm_obs(session: Session, *, window_s: float = 2.0, detect_window_s: float = 1.0) -> ObsTable:
    """Observation windows of another session for the gravity-norm judgement: its labelled holds
    (the norm ignores their orientations), or its detected static intervals when it has none."""
    if session.poses:
        return observations(session, window_s=window_s)
    return detect_holds(session, window_s=detect_window_s, obs_window_s=window_s)[0]


def settle_choice(d: Diagnosis, obs: ObsTable) -> None:
    """A hand-held diagnosis once its out-of-sample choice (d.choice) has spoken, by diagnose's one
    rule: the chosen candidate first and as `best`, the verdict naming it (or saying that no
    significant candidate predicts unseen data better), ties named with what separates them."""
    ch = d.choice
    rank_rows(d.candidates, ch)
    sig = [r for r in d.candidates if r.get("significant")]
    d.best = ch.chosen
    verdict, advice = _handheld_verdict(
        obs, d.model, d.fit, d.candidates, sig if ch.chosen else [], d.missing
    )
    d.verdict, d.advice = with_choice(verdict, advice, ch, sig)
