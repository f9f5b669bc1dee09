"""The model workbench: is the model at the noise floor, and if not, which physical effect is missing?

diagnose(obs, model) fits the model, compares residuals with the noise (chi2/dof against sigma_g),
then tries every library effect as a candidate (model + effect) and ranks them by

- delta chi2 and an F test:  F = (dchi2 / dk) / (chi2_c / dof_c),  p = P(F_{dk, dof_c} > F);
- information criteria:      dBIC = -dchi2 + dk ln m,  dAIC = -dchi2 + 2 dk  (m = equations);
- out of sample:             leave-one-hold-out chi2 per row, r_cv,g = (I - H_gg)^-1 r_g (whitened
                             hat matrix H = J (J^T J)^-1 J^T; exact for linear models, one-step for
                             nonlinear; accellog.calibrate.diagnosis.cross_validation), compared on the holds
                             both models can predict.

A candidate is *significant* when p < alpha / n_candidates, dBIC < -10 and its CV score improves.
The driver-signal view (accellog.calibrate.diagnosis.driver_signals) projects each signal (temperature, its rate, t, t_in_pose, gravity components,
squares, products, rotation about the vertical, user signals) onto the residual after removing what
the model can already absorb: dchi2 = (r . c_perp)^2 / |c_perp|^2 per (signal, axis), so an effect
the library lacks still shows itself. Effects the data cannot reveal are reported with what to record.

A session without pose labels (hand-held, field; diagnose_handheld) observes only the gravity norm
(imu_tk / ArduPilot): e_r = |correct(theta; a'_r, drivers_r)| - g per window, chi2 = sum (e_r /
sigma_n,r)^2 (sigma_n: the window noise projected on the reading), candidates fitted by
fit_orientation_free and judged by the same F test and dBIC. What the norm cannot see is said, not
guessed (NORM_BLIND): a rotation of the sensor frame (3 of cross_axis's 6 terms: misalignment_tri
holds the other 3), the fixture tilt and the sample clock.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from accellog.calibrate.diagnosis.choose import OUT_OF_SESSION, StepChoice, choose_effect
from accellog.calibrate.diagnosis.clock import clock_from_host_time
from accellog.calibrate.diagnosis.cross_validation import cv_compare, cv_scores
from accellog.calibrate.diagnosis.driver_signals import ALPHA, MIN_DRIVER_R2, driver_signals
from accellog.calibrate.model.compose import Model
from accellog.calibrate.model.effects import NORM_BLIND, all_effects
from accellog.calibrate.model.fit import FitResult, fit_model, fit_orientation_free, obs_drivers
from accellog.calibrate.model.identifiability import checked_advice, effect_requirement, norm_blind_reason
from accellog.core.errors import InputError, ModelError
from accellog.core.heap import trim_heap
from accellog.core.numeric import f_sf, normal_sf
from accellog.core.reprs import fit_text, short_repr
from accellog.core.session import ObsTable
from accellog.core.timeseries import LineFit

DBIC_MIN = -10.0
"""A candidate must lower BIC by more than 10 ("very strong" evidence) to count."""
STILL_MISSING = 3.0
"""Above this held-out chi2/eq (window noise alone) the chosen effect is said to leave something."""


@dataclass
class Diagnosis:
    """Result of diagnose(); to_dict() is the --json output."""

    model: Model
    fit: FitResult
    noise_floor_g: float
    missing: bool
    verdict: str
    candidates: list[dict]
    driver_signals: list[dict]
    advice: list[str]
    best: str | None = None
    clock: dict | None = None
    cv_base: float = np.nan
    extra: dict = field(default_factory=dict)
    choice: StepChoice | None = None
    """Out-of-sample judgement of the significant candidates (accellog.calibrate.diagnosis.choose)."""
    fits: dict[str, FitResult] = field(default_factory=dict, repr=False)
    """Fit of model + candidate, by candidate name (identifiable candidates; not in to_dict)."""

    def __repr__(self) -> str:
        """One line for a notebook: the model's fit, missing or not, the chosen effect (core.reprs)."""
        f = self.fit
        stats = fit_text(self.model.name, self.model.n_params, f.chi2_dof, f.rms_g)
        tied = self.choice.undecided if self.choice is not None else []
        return short_repr(
            "Diagnosis",
            [
                stats,
                "something is missing" if self.missing else "nothing is missing",
                self.best and f"best {self.best}",
                tied and f"tied with {', '.join(tied)}",
            ],
        )

    def to_dict(self, max_signals: int = 30) -> dict:
        return {
            "model": self.model.name,
            "model_spec": self.model.to_spec(),
            "n_obs": self.fit.n_obs,
            "chi2": _j(self.fit.chi2),
            "dof": self.fit.dof,
            "chi2_dof": _j(self.fit.chi2_dof),
            "p_value": _j(self.fit.p_value),
            "rms_g": self.fit.rms_g,
            "noise_floor_g": self.noise_floor_g,
            "missing": self.missing,
            "best": self.best,
            "verdict": self.verdict,
            "candidates": [{k: _j(v) for k, v in c.items()} for c in self.candidates],
            "driver_signals": [{k: _j(v) for k, v in s.items()} for s in self.driver_signals[:max_signals]],
            "advice": list(self.advice),
            "clock": self.clock,
            "choice": None if self.choice is None else self.choice.to_dict(),
            "fit": self.fit.to_dict(),
        }


def _j(v):
    if isinstance(v, float) and not np.isfinite(v):
        return None
    if isinstance(v, np.floating):
        return _j(float(v))
    if isinstance(v, np.bool_):
        return bool(v)
    return v


def default_candidates(model: Model) -> list[str]:
    """Every library (and user-file) effect not in the model and not conflicting with it."""
    out = []
    for name, e in all_effects(model.effects_file).items():
        if name in model.term_names:
            continue
        if any(c in model.term_names for c in e.conflicts):
            continue
        out.append(name)
    return out


def diagnose(
    obs: ObsTable,
    model: Model,
    *,
    candidates: Sequence[str] | None = None,
    weighted: bool = True,
    gravity_g: float = 1.0,
    drivers: Mapping[str, np.ndarray] | None = None,
    host_time: LineFit | tuple[np.ndarray, np.ndarray] | None = None,
    heldout: Sequence[ObsTable] | None = None,
    validate: bool = True,
) -> Diagnosis:
    """Fit `model`, test it against the noise floor, rank candidate effects, show driver signals.

    host_time: optional host clock to estimate the sample-clock error: store.stream.HostClock's
    result (a pass over a file), or the (t_sensor_s, t_host_s) sample times (s) of a session.
    validate: judge the significant candidates out of sample (accellog.calibrate.diagnosis.choose: held-out
    sessions `heldout` when given, else blocked validation) and make the best of them `best`.
    The test statistics always use sigma_g (the noise estimate); weighted=False only changes the
    parameter estimates (the seed's unweighted fit).
    """
    sig = np.asarray(obs.sigma_g, float)
    if not (sig.shape == obs.meas_g.shape and np.all(np.isfinite(sig) & (sig > 0))):
        raise InputError("diagnose needs a noise estimate: finite positive sigma_g for every observation")
    drv = obs_drivers(obs, drivers)
    fit_kw: dict[str, Any] = {"weighted": weighted, "gravity_g": gravity_g, "drivers": drivers}
    trim_heap()  # pages the caller freed (e.g. its own fit) are not carried through the candidates
    base = fit_model(obs, model, **fit_kw)
    m_eq = base.residual_g.size
    floor = float(np.sqrt(np.mean(sig**2)))
    cv_b_all = cv_scores(base, obs)
    base.release_jacobian()  # every fit's Jacobian is remade when read: memory of one, not of all
    cands = list(candidates) if candidates is not None else default_candidates(model)
    lib = all_effects(model.effects_file)
    unknown = [c for c in cands if c not in lib]
    if unknown:
        raise ModelError(f"unknown candidate effect(s) {unknown}; valid: {', '.join(lib)}")
    n_tests = max(1, sum(1 for c in cands if lib[c].static))
    rows, fits, clock = _candidate_rows(cands, obs, model, base, cv_b_all, drv, fit_kw, host_time, n_tests)
    choice = choose_effect(base, rows, fits, obs, heldout) if validate else None
    rank_rows(rows, choice)
    signals = driver_signals(base, obs, drv)
    sig_cands = [r for r in rows if r.get("significant") and r["effect"] != "clock"]
    if len(sig_cands) > 1:
        _second_round(sig_cands, obs, model, fit_kw, n_tests, m_eq)
    base_bad = bool(np.isfinite(base.p_value) and base.p_value < ALPHA and base.dof > 0)
    missing = base_bad or bool(sig_cands)
    best = sig_cands[0]["effect"] if sig_cands else None
    if choice is not None:
        best = choice.chosen
    verdict, advice = _verdict(model, base, floor, missing, sig_cands, signals, rows, clock)
    trim_heap()
    if choice is not None:
        verdict, advice = with_choice(verdict, advice, choice, sig_cands)
    return Diagnosis(
        model=model,
        fit=base,
        noise_floor_g=floor,
        missing=missing,
        verdict=verdict,
        candidates=rows,
        driver_signals=signals,
        advice=advice,
        best=best,
        clock=clock,
        cv_base=float(np.sum(cv_b_all[np.isfinite(cv_b_all)]) / max(m_eq, 1)),
        fits=fits,
        choice=choice,
    )


def _candidate_rows(
    cands: Sequence[str],
    obs: ObsTable,
    model: Model,
    base: FitResult,
    cv_b_all: np.ndarray,
    drv: Mapping[str, np.ndarray],
    fit_kw: dict[str, Any],
    host_time: LineFit | tuple[np.ndarray, np.ndarray] | None,
    n_tests: int,
) -> tuple[list[dict], dict[str, FitResult], dict | None]:
    """(rows, fits of model + candidate by name, clock estimate or None): one row per candidate,
    with the statistics of _candidate_stats, the host-clock test, or why it cannot be revealed."""
    lib = all_effects(model.effects_file)
    rows: list[dict] = []
    fits: dict[str, FitResult] = {}
    clock = None
    for name in cands:
        row: dict = {"effect": name, "n_params": len(lib[name].params), "identifiable": False}
        rows.append(row)
        if name == "clock" and host_time is not None:
            clock = clock_from_host_time(host_time)
            row.update(_clock_row(clock))
            continue
        reason = effect_requirement(name, obs, drv, model)
        if reason is not None:  # a recording is recommended only if it would identify the effect
            row["reason"] = checked_advice(model, name, reason) if lib[name].static else reason
            continue
        cm = model.with_terms([name])
        try:
            cr = fit_model(obs, cm, **fit_kw)
        except ModelError as exc:
            row["reason"] = str(exc)
            continue
        fits[name] = cr
        row.update(_candidate_stats(name, cm, cr, model, base, obs, cv_b_all, n_tests))
        cr.release_jacobian()
        trim_heap()  # the fit's temporaries (~3 Jacobians) are freed: give their pages back
    return rows, fits, clock


def _clock_row(clock: dict) -> dict:
    """The clock candidate from host time: significant when |eps| > 5 sigma and > 1 ppm."""
    z = abs(clock["eps_clock"]) / max(clock["sigma"], 1e-300)
    return dict(
        identifiable=True,
        significant=bool(z > 5 and abs(clock["eps_ppm"]) > 1.0),
        p_value=2 * normal_sf(z),
        reason=f"from host time: eps_clock = {clock['eps_ppm']:.1f} +- {clock['sigma_ppm']:.1f} ppm "
        "(sample period is (1 + eps)/ODR; correct integration time, not static readings)",
    )


def _candidate_stats(name, cm, cr, model, base, obs, cv_b_all, n_tests) -> dict:
    """F test, dBIC, dAIC and leave-one-hold-out CV of fit cr (model cm = model + name) vs base."""
    m_eq = base.residual_g.size
    dk = cm.n_params - model.n_params
    dchi2, F, p, dbic = nested_test(base, cr, dk, m_eq)
    cv_c, cv_b, n_cv = cv_compare(cv_scores(cr, obs), cv_b_all, obs)
    daic = -dchi2 + 2 * dk
    sl = cm.slices[name]
    weak = [
        n
        for n, s, t in zip(cm.param_names[sl], cr.sigma[sl], cm.param_typical[sl], strict=True)
        if s > t and n != "tau_warmup_s"
    ]
    signif = bool(cr.dof > 0 and p < ALPHA / n_tests and dbic < DBIC_MIN and (n_cv == 0 or cv_c < cv_b))
    return dict(
        identifiable=True,
        significant=signif,
        chi2_dof=cr.chi2_dof,
        delta_chi2=dchi2,
        delta_chi2_dof=base.chi2_dof - cr.chi2_dof,
        F=F,
        p_value=p,
        delta_bic=float(dbic),
        delta_aic=float(daic),
        cv_chi2_per_eq=cv_c,
        cv_chi2_per_eq_base=cv_b,
        cv_holds=n_cv,
        params={
            n: [float(v), float(s)]
            for n, v, s in zip(cm.param_names[sl], cr.theta[sl], cr.sigma[sl], strict=True)
        },
        reason=(
            f"chi2/dof {base.chi2_dof:.3g} -> {cr.chi2_dof:.3g}, dBIC {dbic:.1f}"
            + (f", CV chi2/eq {cv_b:.3g} -> {cv_c:.3g}" if np.isfinite(cv_b) and np.isfinite(cv_c) else "")
            + (f"; weakly determined: {', '.join(weak)} 1-sigma above typical size" if weak else "")
        ),
    )


def nested_test(base: FitResult, cr: FitResult, dk: int, m_eq: int) -> tuple[float, float, float, float]:
    """(dchi2, F, p, dBIC) of fit cr, dk parameters more than base, over m_eq equations (module doc)."""
    dchi2 = base.chi2 - cr.chi2
    F = (dchi2 / max(dk, 1)) / max(cr.chi2 / max(cr.dof, 1), 1e-300)
    p = f_sf(F, max(dk, 1), max(cr.dof, 1)) if cr.dof > 0 else np.nan
    return dchi2, F, p, -dchi2 + dk * np.log(m_eq)


def rank_rows(rows: list[dict], choice: StepChoice | None) -> None:
    """Attach the out-of-sample scores and sort in place: significant first, the chosen one
    (out-of-sample evidence) first among them, then by the out-of-sample score, then by dBIC
    (identifiable), then the rest; number the rows 1.. as 'rank'."""
    if choice is not None:
        for r in rows:
            if r["effect"] in choice.scores:
                r["oos_chi2_per_eq"] = choice.scores[r["effect"]].chi2_per_eq
                r["oos_evidence"] = choice.evidence

    def _key(r):
        oos = r.get("oos_chi2_per_eq", np.inf)
        dbic = r.get("delta_bic", np.inf)
        return (
            not r.get("significant", False),
            not r["identifiable"],
            choice is None or r["effect"] != choice.chosen,
            oos if np.isfinite(oos) else np.inf,
            dbic if np.isfinite(dbic) else np.inf,
        )

    rows.sort(key=_key)
    for k, r in enumerate(rows, 1):
        r["rank"] = k


def _second_round(sig_cands: list[dict], obs, model, fit_kw, n_tests: int, m_eq: int) -> None:
    """Does each runner-up (2nd..4th) still help on top of the best? Adds 'given_best' (and its p)."""
    mb = model.with_terms([sig_cands[0]["effect"]])
    rb = fit_model(obs, mb, **fit_kw)
    for r in sig_cands[1:4]:
        try:
            r2 = fit_model(obs, mb.with_terms([r["effect"]]), **fit_kw)
        except ModelError as exc:  # not identifiable together, or the joint fit did not converge
            why = str(exc)
            r["given_best"] = (
                f"joint fit with {sig_cands[0]['effect']} did not converge"
                if "converge" in why
                else "not identifiable together with " + sig_cands[0]["effect"]
            )
            continue
        dk = r2.model.n_params - mb.n_params
        F = ((rb.chi2 - r2.chi2) / dk) / max(r2.chi2 / max(r2.dof, 1), 1e-300)
        p2 = f_sf(F, dk, max(r2.dof, 1))
        r["p_value_given_best"] = p2
        r["given_best"] = (
            f"still significant on top of {sig_cands[0]['effect']} (p = {p2:.2g})"
            if p2 < ALPHA / n_tests and (rb.chi2 - r2.chi2) > dk * np.log(m_eq) + 10
            else f"explained by {sig_cands[0]['effect']} (p = {p2:.2g} once it is added)"
        )


def with_choice(verdict: str, advice: list[str], choice: StepChoice, sig_cands: list[dict]):
    """Verdict and advice once the out-of-sample evidence has spoken."""
    if sig_cands and choice.chosen is None:
        head = verdict.split(": residuals")[0].split(": something is missing")[0]
        verdict = (
            f"{head}: something is missing, but no significant candidate predicts unseen data better "
            f"({choice.reason}); it may be a proxy: record a session whose drivers vary independently"
        )
        advice = [a for a in advice if not a.startswith("refit with --add")]
    if choice.undecided and choice.chosen is not None:
        alts = " or ".join(f"--add {e}" for e in [choice.chosen, *choice.undecided])
        advice = [
            f"{alts}: this data cannot tell which is physical; record what separates them (below)"
            if a == f"refit with --add {choice.chosen}"
            else a
            for a in advice
        ]
        verdict += (
            f" Cannot decide between {choice.chosen} and {', '.join(choice.undecided)}: they explain the "
            "same residual on this data."
        )
    chosen = choice.chosen
    left = choice.scores.get(chosen) if chosen is not None else None
    if (
        chosen is not None
        and left is not None
        and choice.evidence in OUT_OF_SESSION
        and left.chi2_per_eq > STILL_MISSING
    ):
        verdict += (
            f" With {chosen.replace('+', ' and ')} the other session is still {left.chi2_per_eq:.3g}x "
            "the window noise (chi2/eq): it predicts unseen data better, not to the noise, so more is "
            "missing (accellog workbench with the same sessions searches on and says what no library "
            "effect explains)."
        )
    tied = set(choice.undecided)
    advice = advice + [c.text() for c in choice.collinear if c.b in tied]
    return verdict, advice


def _verdict(model, base, floor, missing, sig_cands, signals, rows, clock) -> tuple[str, list[str]]:
    ratio = float(np.sqrt(base.chi2_dof)) if np.isfinite(base.chi2_dof) else np.nan
    head = (
        f"{model.name}: chi2/dof = {base.chi2_dof:.3g} (p = {base.p_value:.2g}, dof {base.dof}), "
        f"residual RMS {base.rms_g * 1e3:.3g} mg vs noise floor {floor * 1e3:.3g} mg"
    )
    advice: list[str] = []
    strong_sig = [s for s in signals if s["significant"]]
    if not missing:
        verdict = f"{head}: the model fits to the noise floor; nothing is missing."
    elif sig_cands:
        b = sig_cands[0]
        verdict = (
            f"{head}: residuals are {ratio:.1f}x the noise, something is missing. Most likely: "
            f"{b['effect']} ({b['reason']}, p = {b['p_value']:.2g})."
        )
        advice.append(f"refit with --add {b['effect']}")
        if b["chi2_dof"] > 1.0 + 6.0 * np.sqrt(2.0 / max(base.dof, 1)) and b["chi2_dof"] > 1.5:
            advice.append(
                f"with {b['effect']} chi2/dof is still {b['chi2_dof']:.3g}: more is missing; run diagnose "
                f"again on --model {model.name}+{b['effect']}"
            )
        for r in sig_cands[1:4]:
            if "given_best" in r:
                advice.append(f"{r['effect']}: {r['given_best']}")
    else:
        top = strong_sig[0] if strong_sig else (signals[0] if signals else None)
        verdict = (
            f"{head}: residuals are {ratio:.1f}x the noise, but no identifiable library effect explains them."
        )
        if top is not None and top["partial_r2"] >= MIN_DRIVER_R2:
            advice.append(
                f"strongest unexplained driver signal: {top['signal']} on axis {top['axis']} "
                f"(partial R^2 = {top['partial_r2']:.2f}); write a user effect (docs/effects.md) and "
                "load it with --effects-file"
            )
        elif top is not None:
            advice.append(
                f"no driver signal explains much of the residual (the strongest, {top['signal']} on axis "
                f"{top['axis']}, explains {top['partial_r2']:.0%}): record a session whose drivers vary"
            )
    same: dict[str, list[str]] = {}  # one line per reason: temp_bias, temp_scale, ...: needs temp_degC
    for r in rows:
        if not r["identifiable"] and r.get("reason"):
            same.setdefault(r["reason"], []).append(r["effect"])
    advice += [f"{', '.join(names)}: {reason}" for reason, names in same.items()]
    if clock is not None and abs(clock["eps_ppm"]) > 5 * clock["sigma_ppm"]:
        advice.append(
            f"clock: sample clock off by {clock['eps_ppm']:.0f} ppm: integrate with host-corrected time"
        )
    return verdict, advice


# ---------------------------------------------------------------------------------------------
# hand-held sessions (no pose labels): the gravity norm


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
    rank_rows(rows, None)
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
    dchi2, F, p, dbic = nested_test(base, cr, cr.model.n_params - model.n_params, m_eq)
    sl = cr.model.slices[name]
    return dict(
        identifiable=True,
        significant=bool(cr.dof > 0 and p < ALPHA / n_tests and dbic < DBIC_MIN),
        chi2_dof=cr.chi2_dof,
        delta_chi2=dchi2,
        delta_chi2_dof=base.chi2_dof - cr.chi2_dof,
        F=F,
        p_value=p,
        delta_bic=float(dbic),
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


def settle_choice(d: Diagnosis, obs: ObsTable) -> None:
    """A hand-held diagnosis once its out-of-sample choice (d.choice) has spoken, by diagnose's one
    rule: the chosen candidate first and as `best`, the verdict naming it (or saying that no
    significant candidate predicts unseen data better), ties named with what separates them."""
    ch = d.choice
    assert ch is not None, "settled once the choice is made"
    rank_rows(d.candidates, ch)
    sig = [r for r in d.candidates if r.get("significant")]
    d.best = ch.chosen
    verdict, advice = _handheld_verdict(
        obs, d.model, d.fit, d.candidates, sig if ch.chosen else [], d.missing
    )
    d.verdict, d.advice = with_choice(verdict, advice, ch, sig)
