"""Choose the effect that transfers: one step of the workbench, judged out of sample.

Among the candidates diagnose() calls significant on the calibration data, the step picks the one
with the lowest out-of-sample score (among those within Z_TIE standard errors of the lowest, one
that skips no lower order (Effect.extends: temp_bias before temp_bias2), then the lowest dBIC:
parsimony) (accellog.calibrate.diagnosis.transfer: held-out sessions when given, else blocked
validation over temperature and time). It adds nothing when

    s_base - s_best <= Z_IMPROVE * se(s_best),   se(s) = sqrt(2 / m) max(1, s)

(the best candidate does not predict unseen data better than the base model). Every significant
runner-up whose columns are near-collinear with the best one (canonical correlation > 0.95) is
named with rho and the recording that separates them. The step is *undecided* (the data cannot
tell the two apart, and the verdict says so) when the runner-up's score is within Z_TIE * se of the
best one's with no more parameters, or when, without a held-out session, the two are driven by different kinds of signal
(temperature vs time): blocks of one session cannot separate drivers that move together.

When no single effect passes, two may only together (``choose_pair``): a quadratic temperature
bias and an input nonlinearity each explain a part of the other's residual, so after one of them
neither the other nor a linear temperature term alone predicts unseen data better, while the two
together take the held-out chi2/eq from ~100 to ~2.5 (the hand-held temperature + nonlinearity
sessions of benchmarks/bench_discovery.py). The pairs of the PAIR_TOP candidates that lower the
calibration chi2 most are fitted; a pair is chosen when it is significant on the calibration data
(F test, Bonferroni over the pairs, dBIC < 0) and lowers the out-of-sample score by more than
Z_IMPROVE standard errors below both the base model and the best single candidate.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from accellog.calibrate.diagnosis.transfer import (
    COLLINEAR_RHO,
    Score,
    blocked_scores,
    canonical_correlation,
    driver_kind,
    heldout_score,
    separating_recording,
)
from accellog.calibrate.model.effects import all_effects
from accellog.calibrate.model.fit import FitResult
from accellog.core.session import ObsTable

Z_IMPROVE = 3.0
"""An effect is added only if it lowers the out-of-sample score by more than 3 standard errors."""
Z_TIE = 2.0
"""Two collinear candidates whose scores differ by less than 2 standard errors are a tie."""
PAIR_TOP = 8
"""choose_pair tries the pairs of this many candidates (those that lower the calibration chi2 most)."""
PAIR_ALPHA = 0.01
"""Significance of a pair on the calibration data (F test), Bonferroni-divided over the pairs tried."""


@dataclass
class Collinear:
    """Two candidates that explain the same residual on this data."""

    a: str
    b: str
    rho: float
    separate_by: str

    def to_dict(self) -> dict:
        return {"a": self.a, "b": self.b, "rho": self.rho, "separate_by": self.separate_by}

    def text(self) -> str:
        return (
            f"{self.a} and {self.b} are near-collinear on this data (canonical correlation "
            f"{self.rho:.3f}); what separates them: {self.separate_by}"
        )


@dataclass
class StepChoice:
    """The evidence of one workbench step and what it chose."""

    model: str
    evidence: str
    """'heldout' or 'blocks:<drivers>'."""
    base_score: Score
    scores: dict[str, Score]
    chosen: str | None
    reason: str
    undecided: list[str] = field(default_factory=list)
    collinear: list[Collinear] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {
            "model": self.model,
            "evidence": self.evidence,
            "base_score": self.base_score.to_dict(),
            "scores": {k: v.to_dict() for k, v in self.scores.items()},
            "chosen": self.chosen,
            "undecided": list(self.undecided),
            "collinear": [c.to_dict() for c in self.collinear],
            "reason": self.reason,
        }


OUT_OF_SESSION = ("heldout", "leave-one-session-out")
"""Evidence kinds that predict another session (they break confounds of drivers within one session)."""


def choose_effect(
    base: FitResult,
    candidates: Sequence[dict],
    fits: Mapping[str, FitResult],
    obs: ObsTable,
    heldout: Sequence[ObsTable] | None = None,
    *,
    scores: Callable[[dict[str, FitResult]], dict[str, Score]] | None = None,
    rho: Callable[[FitResult, FitResult], float] | None = None,
) -> StepChoice:
    """Judge the significant candidates (diagnose rows with their fits of base model + effect) out
    of sample and choose one (or none). scores(fits by name, '' = base) -> Score by name replaces
    the default evidence (held-out sessions if given, else blocked validation), e.g. leave one
    session out or the gravity norm of a hand-held session; rho(fit_a, fit_b) replaces the
    canonical correlation of the labelled Jacobian columns."""
    eligible = [c["effect"] for c in candidates if c.get("significant") and c["effect"] in fits]
    model = base.model
    fits = {"": base, **{n: fits[n] for n in eligible}}
    if scores is not None:
        sc = scores(fits)
    elif heldout:
        sc = {n: heldout_score(r, heldout) for n, r in fits.items()}
    else:
        sc = blocked_scores(fits, obs)
    if rho is None:

        def rho(a: FitResult, b: FitResult) -> float:
            return canonical_correlation(a, b, model, obs)

    base_score = sc.pop("")
    evidence = base_score.kind
    if not eligible:
        return StepChoice(model.name, evidence, base_score, sc, None, "no candidate is significant here")
    rows = {c["effect"]: c for c in candidates}

    def score(n: str) -> float:
        v = sc[n].chi2_per_eq
        return v if np.isfinite(v) else np.inf

    s_min = min(score(n) for n in eligible)
    se_min = sc[min(eligible, key=score)].se
    # parsimony among the equally good: the lowest dBIC (fewest parameters for the same fit) wins
    tied_best = [n for n in eligible if score(n) <= s_min + Z_TIE * se_min]
    best = min(tied_best, key=lambda n: (skips_an_order(n, model), rows[n].get("delta_bic", np.inf)))
    ranked = [best, *sorted((n for n in eligible if n != best), key=score)]
    s_best = sc[best]
    what = {"heldout": "held-out", "leave-one-session-out": "leave-one-session-out"}.get(
        evidence, "blocked-validation"
    )
    gain = base_score.chi2_per_eq - s_best.chi2_per_eq
    collinear, undecided = [], []
    for other in ranked[1:]:
        r = rho(fits[best], fits[other])
        if r < COLLINEAR_RHO:
            continue
        collinear.append(Collinear(best, other, r, new_recording(best, other, model, obs)))
        # a tie with an alternative that is no more complex: the data cannot choose
        tie = other in tied_best and rows[other]["n_params"] <= rows[best]["n_params"]
        # within one session, blocks cannot break a confound of two drivers that move together
        # (temperature following time): a difference in score then reflects functional form only
        kinds = {driver_kind(best, model), driver_kind(other, model)}
        confound = evidence not in OUT_OF_SESSION and len(kinds) == 2 and "orientation" not in kinds
        if tie or confound:
            undecided.append(other)
    if not np.isfinite(gain) or gain <= Z_IMPROVE * s_best.se:
        reason = (
            f"{best} is significant here but does not predict unseen data better: {what} chi2/eq "
            f"{base_score.chi2_per_eq:.3g} -> {s_best.chi2_per_eq:.3g} (se {s_best.se:.2g})"
        )
        return StepChoice(model.name, evidence, base_score, sc, None, reason, undecided, collinear)
    reason = f"{best}: {what} chi2/eq {base_score.chi2_per_eq:.3g} -> {s_best.chi2_per_eq:.3g}"
    if len(ranked) > 1:
        r2 = ranked[1]
        reason += f" (next: {r2} {sc[r2].chi2_per_eq:.3g})"
    if undecided:
        reason += f"; cannot tell it from {', '.join(undecided)} on this data"
    return StepChoice(model.name, evidence, base_score, sc, best, reason, undecided, collinear)


def skips_an_order(effect: str, model) -> bool:
    """The effect extends a lower-order one the model lacks (temp_bias2 without temp_bias)."""
    lib = all_effects(model.effects_file)
    return any(e not in model.term_names for e in getattr(lib.get(effect), "extends", ()))


def choose_pair(
    base: FitResult,
    single: StepChoice,
    fits: Mapping[str, FitResult],
    fit: Callable[[ObsTable, object], FitResult],
    obs: ObsTable,
    scores: Callable[[dict[str, FitResult]], dict[str, Score]],
    nested_test: Callable[[FitResult, FitResult, int, int], tuple[float, float, float, float]],
) -> StepChoice | None:
    """Two effects that only together predict unseen data better (module doc), as a StepChoice whose
    chosen is 'a+b' (its scores: the pairs tried and the single candidates), or None. single: the
    step's choice among single effects (it chose nothing); fits: the candidates' fits (model +
    effect); fit(obs, model) fits a pair as the candidates were fitted; nested_test(base, fit, dk,
    m_eq) -> (dchi2, F, p, dBIC): diagnose's test of a richer model."""
    from itertools import combinations

    from accellog.core.errors import ModelError

    if single.evidence not in OUT_OF_SESSION:
        return None
    gain = {n: base.chi2 - r.chi2 for n, r in fits.items() if np.isfinite(r.chi2)}
    top = sorted(gain, key=lambda n: -gain[n])[:PAIR_TOP]
    pairs = list(combinations(top, 2))
    m_eq = int(base.dof + base.model.n_params)
    tried: dict[str, FitResult] = {}
    for a, b in pairs:
        try:
            r = fit(obs, base.model.with_terms([a, b]))
        except ModelError:
            continue
        _, _, p, dbic = nested_test(base, r, r.model.n_params - base.model.n_params, m_eq)
        if np.isfinite(p) and p < PAIR_ALPHA / max(len(pairs), 1) and dbic < 0:
            tried[f"{a}+{b}"] = r
    if not tried:
        return None
    sc = scores({"": base, **tried})
    sc.pop("")

    def value(s: Score) -> float:
        return s.chi2_per_eq if np.isfinite(s.chi2_per_eq) else np.inf

    best = min(sc, key=lambda n: value(sc[n]))
    s_best = sc[best]
    alone = min((value(s) for s in single.scores.values()), default=np.inf)
    floor = min(value(single.base_score), alone)
    if not floor - value(s_best) > Z_IMPROVE * s_best.se:
        return None
    a, b = best.split("+")
    what = {"heldout": "held-out"}.get(single.evidence, single.evidence)
    reason = (
        f"{a} and {b} together: {what} chi2/eq {single.base_score.chi2_per_eq:.3g} -> "
        f"{s_best.chi2_per_eq:.3g} (the best single effect alone {alone:.3g}: each explains part of "
        "the other's residual)"
    )
    return StepChoice(
        base.model.name, single.evidence, single.base_score, {**single.scores, **sc}, best, reason
    )


def heats_and_cools(obs: ObsTable, min_degC: float = 1.0) -> bool:
    """The session's die temperature both rose and fell by >= min_degC (heat then cool, or the reverse)."""
    T = obs.temp_degC
    if T is None or not np.all(np.isfinite(T)) or len(T) < 3:
        return False
    T = np.asarray(T, float)[np.argsort(np.asarray(obs.t_s, float), kind="stable")]
    rise = T - np.minimum.accumulate(T)
    fall = np.maximum.accumulate(T) - T
    return bool(rise.max() >= min_degC and fall.max() >= min_degC)


def new_recording(a: str, b: str, model, obs: ObsTable) -> str:
    """What to record so that a and b stop looking alike (transfer.separating_recording), never a
    recording like the one they were confused on: a session that already heated and cooled is
    told to record another session on another temperature path instead."""
    text = separating_recording(a, b, model)
    if "heat then cool" in text and heats_and_cools(obs):
        text = (
            "this session already heated and cooled: a second session of the sensor on another "
            "temperature path (other soak temperatures, another rate; use it as --heldout)"
        )
    elif "repeats a pose" in text and repeats_a_pose(obs):
        text = "this session already repeats a pose over its length: a second, longer session (--heldout)"
    elif "cube edges" in text and _off_axis(obs):
        text = "this session already has off-axis poses: a second session with other orientations (--heldout)"
    return text


def repeats_a_pose(obs: ObsTable) -> bool:
    """Some orientation is held in the first, the middle and the last third of the session."""
    t = np.asarray(obs.t_s, float)
    if t.size < 3 or np.ptp(t) <= 0:
        return False
    third = np.minimum(((t - t.min()) / np.ptp(t) * 3).astype(int), 2)
    up = np.round(np.asarray(obs.up_sensor, float), 2)
    sets = [{tuple(u) for u in up[third == k]} for k in range(3)]
    return bool(sets[0] & sets[1] & sets[2])


def _off_axis(obs: ObsTable) -> bool:
    up = np.abs(np.asarray(obs.up_sensor, float))
    return bool(np.any(up.max(axis=1) < 0.9))
