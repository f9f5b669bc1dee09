"""The model workbench: the discovery loop, the effects it keeps, the ladder, and `accellog workbench`
as one library call.

The loop (``discover``, on one residual: calibrate.diagnosis.strategy LABELLED per axis, or NORM
the gravity norm e_r = |correct(a'_r)| - g of a hand-held session): diagnose, add the significant
effect that predicts unseen data best (accellog.calibrate.diagnosis.choose), refit, until no
candidate improves out of sample; then the ladder of model-building steps, each judged on the
calibration data (chi^2/dof), on a held-out session (residual RMS vs its noise floor) and on a
static test (|displacement| after 60 s).

    steps: model1 -> model2 -> model3 -> model3 + e1 -> model3 + e1 + e2 ...   (labelled)
           HANDHELD_START -> + e1 -> + e1 + e2 ...                              (hand-held)

``discover`` never adds an effect diagnose does not find significant and identifiable, so a clean
session stops at the start model; it never says "nothing is missing" when the held-out chi2/dof
exceeds HELDOUT_OK, and it names effects the data cannot tell apart instead of choosing silently.

Only effects that earn their place out of sample stay, judged with the loop's own evidence
(held-out sessions, leave one session out, or blocks of one session):

- backward step, after each addition: every earlier effect e is refitted away; e is dropped when

      s(model - e) - s(model) <= Z_IMPROVE se(model)

  (s: out-of-sample chi2 per equation; the forward step's own margin), i.e. a later effect has made
  it redundant, or it was a proxy for what the later one explains;
- proxies, at the end: with evidence from other sessions, a final model that still does not transfer
  (held_out_ok) has not found all the physics. Its added effects are judged one by one on the common
  yardstick (every model with the same repeat-free between-hold scatter,
  calibrate.model.variance.yardstick): an effect whose removal does not worsen the held-out
  chi2/dof is dropped as a proxy, one that makes unseen data better stays (the in-library part of
  what is missing), and no model seen earlier in the search is better held out than the one kept.
  The verdict says what no library effect explains, names the driver the residual follows
  (accellog.calibrate.diagnosis.driver_signals) and points to writing a user effect (docs/effects.md).

``run_workbench``: a labelled session is searched on its poses; a session without pose labels
(hand-held) on its detected static intervals (calibrate.observe.detected_holds.detect_holds) with
the gravity norm, where what the norm cannot identify (a frame rotation, fixture tilt, the clock,
effects the data do not excite) is said in `cannot_identify`, never guessed. Optionally the final
model's calibration file (-o) and a Rerun recording (--rrd). The result is typed
(WorkbenchOutcome); the CLI only presents it. The search's record (every model tried):
accellog.flows.workbench_trail.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from accellog.calibrate.diagnosis.choose import Z_IMPROVE
from accellog.calibrate.diagnosis.driver_signals import MIN_DRIVER_R2
from accellog.calibrate.model.compose import Model, build_model
from accellog.calibrate.model.fit import FitResult, fit_model, obs_drivers
from accellog.core.errors import InputError, ModelError
from accellog.core.jsonio import JsonResult
from accellog.core.session import ObsTable, Session
from accellog.core.timeseries import LineFit

if TYPE_CHECKING:
    from accellog.calibrate.diagnosis.choose import StepChoice
    from accellog.calibrate.diagnosis.diagnose import Diagnosis
    from accellog.calibrate.diagnosis.ladder import LadderRow
    from accellog.calibrate.diagnosis.strategy import ScoreFn, Strategy
    from accellog.calibrate.model.variance import HoldScatter
    from accellog.calibrate.observe.detected_holds import Detection
    from accellog.flows.workbench_trail import TrailStep

BASE_STEPS = ("model1", "model2")


HELDOUT_OK = 2.0
"""Above this held-out chi2/dof the model does not transfer: the verdict never says 'nothing is missing'."""
NOISE_RATIO_OK = 3.0
"""Nor when the noise-only held-out residual RMS exceeds 3x the noise plus the repeat-free scatter."""


def held_out_ok(h: dict) -> bool:
    """Held-out statistics of a model that transfers: predictive chi2/dof <= HELDOUT_OK and, when
    judged on a yardstick, residual RMS <= NOISE_RATIO_OK sqrt(noise^2 + scatter^2)."""
    ok = h["heldout_chi2_dof"] <= HELDOUT_OK
    if h.get("heldout_scatter_g") is not None:
        ok = ok and h["heldout_rms_g"] <= NOISE_RATIO_OK * float(
            np.hypot(h["heldout_noise_g"], h["heldout_scatter_g"])
        )
    return bool(ok)


@dataclass
class Discovery:
    """What the loop found: per step the diagnosis and the out-of-sample choice, the effects added
    (names for --add), and the final verdict that uses all the evidence; a hand-held search also
    the detected intervals, its ladder, and what the gravity norm cannot identify."""

    start: str
    diagnoses: list[Diagnosis] = field(default_factory=list)
    choices: list[StepChoice] = field(default_factory=list)
    added: list[str] = field(default_factory=list)
    heldout: dict | None = None
    """Held-out statistics of the final model (heldout_rms_g, heldout_noise_g, heldout_chi2_dof)."""
    verdict: str = ""
    advice: list[str] = field(default_factory=list)
    undecided: list[list[str]] = field(default_factory=list)
    """Groups of effects the data cannot tell apart (first: the one added)."""
    dropped: list[dict] = field(default_factory=list)
    """Effects added and then dropped: {effect, why} (a backward step, or a proxy that did not
    make the model transfer: prune)."""
    loso: list[dict | None] | None = None
    """With several calibration sessions: the final model's held-out statistics per left-out session."""
    yardstick: dict | None = None
    """The between-hold scatter every model was judged with held out (variance.yardstick: from
    replicate holds of the richest model, or its residual), with its source."""
    scatter: HoldScatter | None = field(default=None, repr=False)
    """The yardstick itself (variance.HoldScatter), for the ladder's held-out columns."""
    final_diagnosis: Diagnosis | None = field(default=None, repr=False)
    """The diagnosis of the final model when pruning made it another than the last step's."""
    trail: list[TrailStep] = field(default_factory=list)
    """Every model the search tried, in order, with its held-out residual on the yardstick
    (accellog.flows.workbench_trail.TrailStep: kept, dropped, tied, rejected, removed)."""
    detection: Detection | None = None
    """A hand-held search: the static intervals detected (None: a labelled session)."""
    obs: ObsTable | None = field(default=None, repr=False)
    """A hand-held search: the windows judged (the verdict names the driver of their norm residual)."""
    ladder: list[LadderRow] = field(default_factory=list)
    """A hand-held search: the ladder start -> + each found effect on the gravity norm."""
    ladder_loso: list[list[dict | None]] = field(default_factory=list)
    """With several calibration sessions: per ladder row, its held-out statistics per left-out session."""

    @property
    def final_model(self) -> str:
        return "+".join([self.start, *self.added])

    @property
    def decided(self) -> bool:
        return not self.undecided

    def __repr__(self) -> str:
        """One line for a notebook: start, what was added and dropped, the final held-out verdict."""
        from accellog.core.reprs import short_repr

        h = self.heldout
        held = None if h is None else f"held-out chi2/dof {h['heldout_chi2_dof']:.3g}"
        return short_repr(
            "Discovery",
            [
                self.start,
                self.added and "+" + "+".join(self.added),
                self.dropped and f"dropped {', '.join(x['effect'] for x in self.dropped)}",
                held,
                {True: "transfers", False: "does not transfer", None: None}[self.transfers],
            ],
        )

    @property
    def transfers(self) -> bool | None:
        """The final model transfers (None without a held-out session): see held_out_ok."""
        return None if self.heldout is None else held_out_ok(self.heldout)

    @property
    def cannot_identify(self) -> list[str]:
        """The last diagnosis's statements of what the norm (or this data) cannot identify."""
        return [a for a in self.diagnoses[-1].advice if not a.startswith("refit with")]

    def to_json(self) -> dict:
        """The workbench's --json keys besides session (and, labelled, the ladder); a hand-held search
        (detection set) also 'handheld', what the norm cannot identify, the detected intervals and its
        ladder, and no yardstick (the keys in the order the workbench has always printed them)."""
        hand = self.detection is not None
        verdicts = {"verdicts": [d.verdict for d in self.diagnoses]}
        out = {
            **({"handheld": True} if hand else {}),
            "start": self.start,
            "added": list(self.added),
            "final_model": self.final_model,
            "verdict": self.verdict,
            **(verdicts if hand else {}),
            "decided": self.decided,
            "undecided": [list(u) for u in self.undecided],
            "transfers": self.transfers,
            "heldout": self.heldout,
            **({} if hand else verdicts),
            "steps": [c.to_dict() for c in self.choices],
            "advice": list(self.advice),
            "dropped": [dict(d) for d in self.dropped],
            **({} if hand else {"yardstick": self.yardstick}),
            "trail": [t.to_dict() for t in self.trail],
            **({} if self.loso is None else {"heldout_per_session": self.loso}),
        }
        if self.detection is not None:  # hand-held
            out["cannot_identify"] = self.cannot_identify
            out["detected"] = self.detection.to_dict()
            out["ladder"] = [r.to_dict() for r in self.ladder]
        return out


def discover(
    obs: ObsTable,
    start: str = "model3",
    *,
    heldout: Sequence[ObsTable] | ObsTable | None = None,
    max_steps: int = 4,
    effects_file: str | Path | None = None,
    host_time: LineFit | None = None,
    on_step: Callable[[object], None] | None = None,
    sessions: Sequence[ObsTable] | None = None,
    strategy: Strategy | None = None,
    found: Discovery | None = None,
) -> Discovery:
    """Diagnose `start`, add the significant candidate that predicts unseen data best (held-out
    sessions if given, else blocked validation over temperature and time), repeat while one
    improves out of sample. on_step(Diagnosis) is called after each step (its .choice: the
    out-of-sample judgement). sessions: the windows of each of several calibration sessions (obs
    is then their concatenation, calibrate.loso.concat_obs): candidates are judged by leaving one
    session out (calibrate.loso) instead. strategy: the residual judged (calibrate.diagnosis.strategy:
    LABELLED per axis, the default, or NORM, the gravity norm of a hand-held session); found: the
    Discovery to fill (a hand-held one with its detection), default a new one."""
    from accellog.calibrate.diagnosis.strategy import LABELLED

    held = [heldout] if isinstance(heldout, ObsTable) else list(heldout or [])
    found = found if found is not None else Discovery(start=start)
    with small_problem_threads():
        _search(found, obs, held, list(sessions or []), strategy or LABELLED, max_steps, effects_file, host_time,
                on_step)  # fmt: skip
    found.verdict, found.advice = final_verdict(found, strategy or LABELLED)
    return found


def _step_choice(out: Discovery, d, obs, held, parts, strategy, max_steps: int):
    """The step's choice (None past max_steps); when no single effect helps, two that only together
    do (Strategy.choose_pair), the single step's candidates then noted as rejected on the trail."""
    from accellog.flows import workbench_trail as trail

    ch = d.choice if len(out.added) < max_steps else None
    trail.note_start(out, ch)
    if ch is not None and ch.chosen is None and len(out.added) + 2 <= max_steps:
        pair = strategy.choose_pair(d, obs, held, parts)
        if pair is not None:
            trail.note_rejected(out, ch)
            ch = pair
    return ch


def small_problem_threads():
    """Single-threaded BLAS for the workbench's many small (~1000 x 20) least-squares problems:
    threads only add overhead there, and oversubscribe a loaded machine (10x slower at load 12)."""
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=1, user_api="blas")


def _search(out: Discovery, obs, held, parts, strategy, max_steps, effects_file, host_time, on_step) -> None:
    """discover's forward loop, backward steps, held-out statistics and proxies (module doc)."""
    from accellog.calibrate.diagnosis.diagnose import default_candidates
    from accellog.calibrate.model.variance import yardstick
    from accellog.flows import workbench_trail as trail

    start = out.start
    model = build_model(start, effects_file=effects_file)
    scores = strategy.scores(obs, held, parts)
    gone: set[str] = set()
    for _ in range(max_steps + 1):
        cands = [c for c in default_candidates(model) if c not in gone]
        d = strategy.diagnose(obs, model, candidates=cands, host_time=host_time, heldout=held)
        if len(parts) > 1 or (d.choice is None and len(out.added) < max_steps):
            strategy.choose(d, obs, held, parts)
        out.diagnoses.append(d)
        if on_step is not None:
            on_step(d)
        ch = _step_choice(out, d, obs, held, parts, strategy, max_steps)
        if ch is not None:
            out.choices.append(ch)
        new = [] if ch is None or ch.chosen is None else ch.chosen.split("+")
        if not new or set(new) & set(out.added):
            trail.note_rejected(out, ch)
            break
        if ch.undecided:
            out.undecided.append([ch.chosen, *ch.undecided])
        out.added.extend(new)
        trail.note_added(out, ch)
        model = model.with_terms(new)
        full = d.fits.get(ch.chosen)
        while (
            drop := backward_step(out.added, start, effects_file, obs, scores, full, strategy.fit)
        ) is not None:
            out.added.remove(drop[0])
            out.dropped.append({"effect": drop[0], "why": drop[1]})
            trail.note_removed(out, drop[0], "backward", drop[1])
            gone.add(drop[0])
            model, full = build_model(start, add=out.added, effects_file=effects_file), None

    yard = None  # one yardstick for every model compared: the richest model's repeat-free scatter
    if held or len(parts) > 1:
        rich = strategy.fit(obs, build_model(out.final_model, effects_file=effects_file))
        yard, source = yardstick(rich, obs)
        out.yardstick = {**yard.to_dict(), "source": source, "model": out.final_model}
        out.scatter = yard
    cache: dict[frozenset, tuple] = {}

    def stats_of(name: str) -> dict | None:
        m = build_model(name, effects_file=effects_file)
        key = frozenset(m.term_names)
        if key not in cache:
            stats, per = strategy.final_stats(obs, m, held, parts, scatter=yard)
            if stats is not None and (out.yardstick or {}).get("source") != "replicates":
                stats["heldout_scatter_g"] = 0.0  # no replicates: scatter cannot be told from model error
            cache[key] = stats, per
        stats, per = cache[key]
        if per is not None:
            out.loso = per
        return stats

    out.heldout = stats_of(out.final_model)
    _prune(out, stats_of, yard is not None)
    out.heldout = stats_of(out.final_model)  # (and the final model's per-session statistics)
    if out.diagnoses and set(out.diagnoses[-1].model.term_names) != set(
        build_model(out.final_model, effects_file=effects_file).term_names
    ):
        final = next((x for x in out.diagnoses if x.model.name == out.final_model), None)
        if final is None:  # pruned to a model no step diagnosed: its own diagnosis for the verdict
            final = strategy.diagnose(obs, build_model(out.final_model, effects_file=effects_file),
                                      host_time=host_time, heldout=held, validate=False)  # fmt: skip
        out.final_diagnosis = final
    # a tie is resolved when every alternative ended up in the model too (or its choice was dropped)
    out.undecided = [
        g
        for g in ([g[0], *[e for e in g[1:] if e not in out.added]] for g in out.undecided)
        if len(g) > 1 and g[0] in out.added
    ]


def _prune(out: Discovery, stats_of, judged: bool) -> None:
    """prune on the models the search walked through, each proxy removed also a
    trail row; then every trail row's held-out statistics (judged: on the common yardstick)."""
    from accellog.flows.workbench_trail import finish_trail, note_removed

    path = ["+".join([out.start, *out.added[:k]]) for k in range(len(out.added))]  # the models seen before
    left = list(out.added)  # as pruning removes them, one trail row each
    for e, why in prune(out, stats_of, path):
        out.dropped.append({"effect": e, "why": why, "proxy": True})
        left.remove(e)
        note_removed(out, e, "proxy", why, left)
    finish_trail(out, stats_of if judged else None)


def final_verdict(found: Discovery, strategy: Strategy | None = None) -> tuple[str, list[str]]:
    """One verdict from all the evidence: the last diagnosis, the held-out session, the ties (the
    gravity norm's words for a NORM search)."""
    norm = strategy.norm if strategy is not None else ""
    proxies = [x["effect"] for x in found.dropped if x.get("proxy")]
    d = found.final_diagnosis or found.diagnoses[-1]  # the final model's (after pruning)
    parts, extra, held_ok = evidence_parts(found, norm=norm, diagnosis=d)
    if norm:
        if not parts:
            return d.verdict.rstrip(".") + held_ok + ".", extra
        head = f"{d.model.name}: norm chi2/dof {d.fit.chi2_dof:.3g} on the calibration session"
        return f"{head}; " + "; ".join(parts) + held_ok + ".", extra
    where = "the calibration session" + ("s" if found.loso else "")
    fit = f"{d.model.name}: chi2/dof {d.fit.chi2_dof:.3g} on {where}"
    advice = [a for a in d.advice if not any(e in a for e in proxies)] + extra
    if not parts and not d.missing:
        return f"{fit}: the model fits to the noise floor; nothing is missing{held_ok}.", advice
    if not parts:
        return d.verdict + held_ok, advice
    return f"{fit}; " + "; ".join(parts) + held_ok + ".", advice


def evidence_parts(found: Discovery, norm: str, diagnosis=None) -> tuple[list[str], list[str], str]:
    """(verdict parts, advice, held-out suffix) of a discovery's ties, refusals, dropped effects and
    held-out result, shared by the labelled and hand-held workbenches (norm = "norm " names the
    gravity-norm residual; diagnosis: that of the final model, default the last)."""
    d = diagnosis if diagnosis is not None else found.diagnoses[-1]
    dropped = list(found.dropped)
    proxies = [x["effect"] for x in dropped if x.get("proxy")]
    parts, advice = [], [f"{x['effect']}: {x['why']}" for x in dropped]
    tied = {e for group in found.undecided for e in group}
    advice += [col.text() for c in found.choices for col in c.collinear if col.b in tied]
    if found.undecided:
        groups = "; ".join(" vs ".join(u) for u in found.undecided)
        parts.append(
            f"cannot decide between {groups}: they explain the same {norm}residual on this data, so the "
            "added effect may be a proxy that will not transfer (see advice for what to record)"
        )
    last = found.choices[-1] if found.choices else None
    if last is not None and last.chosen is None and "does not predict" in last.reason:
        parts.append(last.reason)
    h = found.heldout
    if h is not None and not found.transfers:
        fits = "fits here but " if not d.missing else ""
        parts.append(
            f"the model {fits}does not transfer: held-out {norm}chi2/dof {h['heldout_chi2_dof']:.3g} "
            f"(residual {h['heldout_rms_g'] * 1e3:.3g} mg vs noise {h['heldout_noise_g'] * 1e3:.3g} mg)"
        )
        advice.append(
            "what is missing shows only on the held-out session: run diagnose on it, or record a "
            "session whose drivers (temperature, time, orientation) vary independently"
            if not d.missing
            else "no library effect transfers: describe the missing term as a user effect (docs/effects.md)"
        )
    # still missing, and no library effect was taken at the last step (or none transfers)
    stuck = last is None or last.chosen is None or found.transfers is False
    if proxies or (d.missing and stuck) or found.transfers is False:
        parts.append(no_library_effect(d, proxies, norm, found.obs))
    held_ok = ""
    if found.transfers and h is not None:  # a model that misses something transfers only within its scatter
        held_ok = f" (held-out {norm}chi2/dof {h['heldout_chi2_dof']:.3g}: " + (
            "within the calibration's own scatter)" if d.missing else "it transfers)"
        )
    return parts, advice, held_ok


# ---------------------------------------------------------------------------------------------
# the effects that earn their place (module doc)


def backward_step(
    added: list[str],
    start: str,
    effects_file,
    obs: ObsTable,
    scores: ScoreFn,
    full: FitResult | None = None,
    fit: Callable[[ObsTable, Model], FitResult] = fit_model,
) -> tuple[str, str] | None:
    """(effect, why) for the earlier added effect whose removal costs least out of sample, when it
    costs no more than Z_IMPROVE standard errors (module doc); None when every one earns its place.
    full: the fit of start + added (refitted when not given); fit: fit_model, or
    fit_orientation_free for hand-held sessions."""
    if len(added) < 2:
        return None

    def fit_of(effects: list[str]) -> FitResult:
        return fit(obs, build_model(start, add=effects, effects_file=effects_file))

    fits = {"": full if full is not None else fit_of(added)}
    for e in added[:-1]:
        try:
            fits[e] = fit_of([a for a in added if a != e])
        except ModelError:
            continue
    sc = scores(fits)
    s_full = sc.pop("")
    if not sc:
        return None
    e = min(sc, key=lambda n: sc[n].chi2_per_eq if np.isfinite(sc[n].chi2_per_eq) else np.inf)
    cost = sc[e].chi2_per_eq - s_full.chi2_per_eq
    if not cost <= Z_IMPROVE * s_full.se:
        return None
    why = (
        f"dropped after {added[-1]} was added: without it the out-of-sample chi2/eq is "
        f"{sc[e].chi2_per_eq:.3g} vs {s_full.chi2_per_eq:.3g} with it (se {s_full.se:.2g}), "
        "so it no longer earns its place"
    )
    return e, why


def residual_driver(diagnosis, obs: ObsTable | None = None) -> str:
    """'<signal> on axis <a> (partial R^2 = ..)' for the strongest significant driver signal of a
    diagnosis's residual (or its strongest signal); for a hand-held diagnosis (no signal table)
    the driver that explains most of the gravity-norm residual (R^2 of a straight line; obs: its
    windows); '' when there is none."""
    sigs = getattr(diagnosis, "driver_signals", None) or []
    top = next((s for s in sigs if s.get("significant")), sigs[0] if sigs else None)
    if top is not None:
        if top["partial_r2"] < MIN_DRIVER_R2:  # a driver is named only when it explains a real share
            return ""
        return f"{top['signal']} on axis {top['axis']} (partial R^2 = {top['partial_r2']:.2f})"
    if obs is None:
        return ""
    res = diagnosis.fit
    drv = obs_drivers(obs)
    f = res.model.correct(res.theta, np.asarray(obs.meas_g, float), drv)
    fn = np.linalg.norm(f, axis=1)
    e, fhat = fn - res.gravity_g, f / fn[:, None]
    best, r2 = "", 0.0
    for name in ("temp_degC", "dtemp_degC_per_s", "t_s", "t_in_pose_s"):
        x = drv.get(name)
        if x is None or np.ptp(x) == 0 or np.ptp(e) == 0:
            continue
        for i, a in enumerate("xyz"):  # a bias b_i(x) on axis i shows in the norm as fhat_i b_i(x)
            c = float(np.corrcoef(fhat[:, i] * (x - np.mean(x)), e)[0, 1]) ** 2
            if c > r2:
                best, r2 = f"{name} on axis {a}", c
    return f"{best} (R^2 = {r2:.2f} with the gravity-norm residual)" if best and r2 >= MIN_DRIVER_R2 else ""


def no_library_effect(
    diagnosis, proxies: Sequence[str] = (), norm: str = "", obs: ObsTable | None = None
) -> str:
    """The verdict part that says no library effect explains what is left (module doc)."""
    drv = residual_driver(diagnosis, obs)
    text = "no library effect explains what is left"
    if proxies:
        text += f" ({', '.join(proxies)} fitted here but did not make the {norm}model transfer: dropped as proxies)"
    text += f"; the residual follows {drv}" if drv else "; no single driver signal explains the residual"
    return text + "; write a user effect for it (docs/effects.md) and load it with --effects-file"


def prune(found, stats_of: Callable[[str], dict | None], seen: Sequence[str] = ()) -> list[tuple[str, str]]:
    """When the final model does not transfer: drop, one at a time, the added effect whose removal
    lowers the held-out chi2/dof on the common yardstick most, while a removal does not raise it
    (an effect that makes the held-out residual better stays: never all or nothing); then, if a
    model seen earlier in the search (seen: their names) is better held out, return to it. Returns
    (effect, why) per dropped effect; found.added shrinks. Nothing happens without out-of-session
    evidence or when the final model transfers."""
    if not found.added or found.heldout is None or found.transfers is not False:
        return []
    out: list[tuple[str, str]] = []
    cur = found.heldout

    def chi2(st: dict | None) -> float:
        return np.inf if st is None else float(st["heldout_chi2_dof"])

    while found.added:
        trials = {
            e: stats_of("+".join([found.start, *[a for a in found.added if a != e]])) for e in found.added
        }
        e = min(trials, key=lambda k: chi2(trials[k]))
        if chi2(trials[e]) > chi2(cur):
            break
        out.append((e, f"a proxy: without it the held-out chi2/dof is {chi2(trials[e]):.3g}, with it "
                       f"{chi2(cur):.3g} (the same yardstick): it does not help unseen data"))  # fmt: skip
        found.added.remove(e)
        cur = trials[e]
    best = min(seen, key=lambda n: chi2(stats_of(n)), default=None)
    if best is not None and chi2(stats_of(best)) < chi2(cur):
        terms = best.split("+")[1:] if best != found.start else []
        gone = [e for e in found.added if e not in terms]
        why = f"an earlier model of the search, {best}, predicts unseen data better ({chi2(stats_of(best)):.3g} vs {chi2(cur):.3g})"
        out += [(e, why) for e in gone]
        found.added = [e for e in found.added if e in terms]
    return out


# ---------------------------------------------------------------------------------------------
# the ladder


def ladder_rows(
    calibration: Session,
    obs: ObsTable,
    steps: Sequence[tuple[str, list[str]]],
    *,
    heldout: Sequence[ObsTable] | ObsTable | None = None,
    static_test: Session | None = None,
    effects_file: str | Path | None = None,
    at_s: float = 60.0,
    gyro: bool = True,
    scatter=None,
    strategy: Strategy | None = None,
    sessions: Sequence[ObsTable] = (),
    per_session: list[list[dict | None]] | None = None,
) -> list[LadderRow]:
    """Fit each step (preset, added effects) and judge it: chi2/dof and RMS on the calibration
    windows; held-out residual RMS and noise floor (g) and predictive chi2/dof (on scatter: the
    search's one yardstick), averaged over the held-out sessions or, with several calibration
    sessions (their windows: obs, concatenated), over the sessions left out one by one (each row's
    per-session statistics appended to per_session); |displacement| of the static test at at_s (m).
    strategy: LABELLED (default) or NORM (orientation-free fits on the gravity norm). Each row keeps
    its FitOutcome in .fit (not JSON); gyro: calibrate the gyro with the last step (for the file)."""
    from accellog.calibrate.diagnosis.ladder import ladder_row
    from accellog.calibrate.diagnosis.loso import loso_stats, mean_stats
    from accellog.calibrate.diagnosis.strategy import LABELLED
    from accellog.flows.stages import run_fit

    strategy = strategy or LABELLED
    held = [heldout] if isinstance(heldout, ObsTable) else list(heldout or [])
    rows = []
    with small_problem_threads():
        for i, (preset, add) in enumerate(steps):
            fo = run_fit(calibration, preset, add=list(add), effects_file=effects_file, obs=obs,
                         orientation_free=strategy.on_norm, gyro=gyro and i == len(steps) - 1)  # fmt: skip
            row = ladder_row(fo.fit, added=add, fit=fo)
            if len(sessions) > 1:
                per = loso_stats(sessions, fo.fit.model, strategy.fit,
                                 lambda r, o: strategy.heldout_stats(r, o, scatter))  # fmt: skip
                if per_session is not None:
                    per_session.append(per)
                stats = mean_stats(per)
            else:
                stats = strategy.mean_heldout_stats(fo.fit, held, scatter) if held else {}
            for key, v in stats.items():
                setattr(row, key, v)
            if static_test is not None:
                add_static_drift(row, static_test, at_s)
            rows.append(row)
    return rows


def add_static_drift(row: LadderRow, static_test: Session, at_s: float) -> None:
    """Set row.drift_m: |displacement| (m) of the static test integrated with the row's calibration
    (row.fit: a FitOutcome) at at_s (s)."""
    from accellog.flows.stages import run_evaluate

    fo = row.fit
    ev = run_evaluate(static_test, [fo.cal], include_raw=False, labels=[fo.fit.model.name], times_s=(at_s,))[
        0
    ]
    row.drift_m, row.drift_at_s = float(np.linalg.norm(ev.disp_at(at_s))), float(at_s)


def steps_for(discovery: Discovery) -> list[tuple[str, list[str]]]:
    """model1, model2, the start model, then one step per added effect, a pair added together one
    step (a hand-held search: from its start model, model1 and model2 being no steps of an
    orientation-free fit)."""
    hand = discovery.detection is not None
    steps: list[tuple[str, list[str]]] = [(p, []) for p in BASE_STEPS if p != discovery.start and not hand]
    steps.append((discovery.start, []))
    pairs = [set(c.chosen.split("+")) for c in discovery.choices if c.chosen and "+" in c.chosen]
    added, k = discovery.added, 0
    while k < len(added):
        k += 2 if set(added[k : k + 2]) in pairs else 1
        steps.append((discovery.start, added[:k]))
    return steps


def log_ladder(rec, rows: Sequence[LadderRow], obs: ObsTable) -> None:
    """The ladder in a RunRecording (bars per metric, log10), with the residuals of the start model
    and of the final model next to the temperature (the usual driver of what was missing)."""
    show = {len(rows) - 1} | {i for i, r in enumerate(rows) if not r.added and r.model not in BASE_STEPS}
    rec.log_ladder(
        rows,
        t_s=np.asarray(obs.t_s),
        driver=None if obs.temp_degC is None else np.asarray(obs.temp_degC),
        driver_name="temperature (degC)",
        residual_steps=show,
    )


# ---------------------------------------------------------------------------------------------
# `accellog workbench` (module doc)


@dataclass
class WorkbenchOutcome(JsonResult):
    """One workbench run: what the loop found (a Discovery; with its detection for an unlabelled
    session), the ladder, and the calibration file written (if any)."""

    session: str
    found: Discovery
    ladder: list[LadderRow]
    output: str | None = None
    notes: list[str] = field(default_factory=list)
    """Remarks about the inputs (e.g. an option not used on this kind of session)."""
    sessions: list[str] = field(default_factory=list)
    """All calibration sessions when there are several (session is the first)."""
    ladder_loso: list[list[dict | None]] = field(default_factory=list)
    """With several sessions: per ladder row, held-out statistics per left-out session."""

    def loso_dict(self) -> dict | None:
        """The leave-one-session-out evidence: per ladder step, held-out chi2/dof and RMS (g) of
        each session predicted by the fit to the others."""
        if len(self.sessions) < 2:
            return None

        def col(per, key):
            return [None if p is None else p[key] for p in per]

        return {
            "sessions": list(self.sessions),
            "steps": [
                {
                    "model": r.model,
                    "added": list(r.added),
                    "heldout_chi2_dof": col(per, "heldout_chi2_dof"),
                    "heldout_rms_g": col(per, "heldout_rms_g"),
                    "heldout_noise_g": col(per, "heldout_noise_g"),
                }
                for r, per in zip(self.ladder, self.ladder_loso, strict=True)
            ],
        }

    @property
    def handheld(self) -> bool:
        return self.found.detection is not None

    @property
    def ok(self) -> bool:
        """The loop decided, the final model transfers (or no held-out session) and nothing is missing."""
        f = self.found
        return f.decided and f.transfers is not False and not f.diagnoses[-1].missing

    def to_dict(self) -> dict:
        """workbench --json: session, the loop's keys and the ladder; with several calibration
        sessions also `sessions` and `leave_one_session_out` (loso_dict)."""
        out = {"session": self.session, **self.found.to_json()}
        if not self.handheld:
            out["ladder"] = [r.to_dict() for r in self.ladder]
        if len(self.sessions) > 1:
            out["sessions"] = list(self.sessions)
            out["leave_one_session_out"] = self.loso_dict()
        return out


def run_workbench(
    session: str | Path | Sequence[str | Path],
    *,
    heldout: Sequence[str | Path] = (),
    static: str | Path | None = None,
    model: str = "model3",
    max_steps: int = 4,
    effects_file: str | Path | None = None,
    at_s: float = 60.0,
    output: str | Path | None = None,
    rrd: str | Path | None = None,
    on_step: Callable[[object], None] | None = None,
) -> WorkbenchOutcome:
    """Run the workbench on one session file, or on several calibration sessions of one sensor
    (fitted together, each candidate judged by leaving one session out: calibrate.loso), see the
    module doc; on_step(Diagnosis) after each step of a labelled session's loop (progress)."""
    from accellog.store.source import open_source

    paths = [session] if isinstance(session, (str, Path)) else list(session)
    datas = [open_source(p, what="the workbench").whole() for p in paths]
    if len(paths) > 1 and heldout:
        raise InputError(
            "give several calibration sessions (each is left out in turn) or --heldout, not both",
            where=str(heldout[0]),
        )
    if len({bool(d.poses) for d in datas}) > 1:
        raise InputError(
            "several calibration sessions must all have pose labels or all be hand-held (none)",
            where=", ".join(str(p) for p in paths),
        )
    test = open_source(static, what="--static").whole() if static is not None else None
    if not datas[0].poses:  # hand-held: detected static intervals, gravity-norm residual
        out = _handheld(datas, paths[0], heldout, model, max_steps, effects_file, test, at_s, output, rrd)
    else:
        out = _labelled(
            datas, paths[0], heldout, test, model, max_steps, effects_file, at_s, output, rrd, on_step
        )
    if len(paths) > 1:
        out.sessions = [str(p) for p in paths]
    return out


def _labelled(
    datas, session, heldout, test, model, max_steps, effects_file, at_s, output, rrd, on_step
) -> WorkbenchOutcome:
    from accellog.calibrate.diagnosis.loso import concat_obs
    from accellog.calibrate.observe.segment import observations
    from accellog.store.source import open_source
    from accellog.store.stream import HostClock

    data = datas[0]
    parts = [observations(d) for d in datas]
    obs = concat_obs(parts) if len(parts) > 1 else parts[0]
    helds = [observations(open_source(h, what="--heldout").whole()) for h in heldout]
    host = None  # the host clock of one session (several sessions: not one clock)
    if (
        len(datas) == 1
        and data.host_time_s is not None
        and np.all(np.isfinite(data.host_time_s))
        and data.n > 2
    ):
        host = HostClock.of(data.t_s, data.host_time_s)
    found = discover(
        obs,
        model,
        heldout=helds,
        max_steps=max_steps,
        effects_file=effects_file,
        host_time=host,
        on_step=on_step,
        sessions=parts if len(parts) > 1 else None,
    )
    ladder_loso: list[list[dict | None]] = []
    rows = ladder_rows(
        data,
        obs,
        steps_for(found),
        heldout=helds[:1],  # the ladder's held-out columns: the first held-out session
        static_test=test,
        effects_file=effects_file,
        at_s=at_s,
        gyro=output is not None or rrd is not None,  # the gyro goes into the calibration file / .rrd
        scatter=found.scatter,
        sessions=parts,
        per_session=ladder_loso,
    )
    if output is not None:
        with_notes(rows[-1].fit.cal, found).save(output)
    if rrd is not None:
        _write_rrd(rrd, data, found, rows, obs)
    return WorkbenchOutcome(
        str(session), found, rows, None if output is None else str(output), ladder_loso=ladder_loso
    )


def with_notes(cal, found):
    """The calibration with the workbench's reservations in fit.warnings: a tied choice (which
    effects the data could not tell apart, what was written, what would separate them) and the
    effects dropped as proxies."""
    import dataclasses

    notes = []
    for group in found.undecided:
        notes.append(
            f"workbench: {group[0]} was written but this data cannot tell it from "
            f"{', '.join(group[1:])} (a tied choice, possibly a proxy that will not transfer)"
        )
    tied = {e for g in found.undecided for e in g}
    notes += [
        f"workbench: what separates them: {c.separate_by}"
        for ch in found.choices
        for c in ch.collinear
        if c.a in tied and c.b in tied
    ]
    notes += [f"workbench: {d['effect']} not written: {d['why']}" for d in found.dropped if d.get("proxy")]
    if not notes:
        return cal
    cal.fit = dataclasses.replace(cal.fit, warnings=(*(cal.fit.warnings or ()), *dict.fromkeys(notes)))
    return cal


def _write_rrd(rrd, data, found, rows, obs) -> None:
    from accellog.present.rrd.recording import RunRecording
    from accellog.present.views import log_diagnosis, log_session

    with RunRecording(f"save:{rrd}") as rec:
        log_session(rec, data, calibrations={found.final_model: rows[-1].fit.cal})
        for i, d in enumerate(found.diagnoses, 1):
            log_diagnosis(rec, d, obs, label=f"step {i}")
        log_ladder(rec, rows, obs)
        log_story(rec, found, rows, obs, rows[-1].fit.fit)


def log_story(rec, found, rows, obs, final_fit) -> None:
    """What carries a workbench recording: the search (every model tried, its held-out residual) and
    the residual against the driver it follows, start model (before) and final model (after), each
    in its ladder step's colour."""
    from accellog.present.residual_views import followed_driver, log_workbench_residuals
    from accellog.present.rrd.logs import step_color
    from accellog.present.search_views import log_search

    log_search(rec, found.trail, rows)
    first = next((i for i, r in enumerate(rows) if not r.added and r.model == found.start), 0)
    colors = (step_color(first), step_color(len(rows) - 1))
    start = found.diagnoses[0]
    log_workbench_residuals(rec, obs, start.fit, final_fit, colors, followed_driver(start))


def _handheld(
    datas, session, heldout, model, max_steps, effects_file, test, at_s, output, rrd
) -> WorkbenchOutcome:
    """The workbench on unlabelled sessions: the static intervals of each detected
    (calibrate.observe.detected_holds), then discover on the gravity norm (strategy NORM; start:
    HANDHELD_START unless another model than model3 is asked: model3's cross_axis is not
    identifiable here) and the ladder start -> + each found effect. Held-out sessions (labelled or
    not: norm_obs) are judged on their gravity norm; several calibration sessions are fitted
    together, candidates judged by leaving one session out (the detection: the first session's)."""
    from accellog.calibrate.diagnosis.loso import concat_obs
    from accellog.calibrate.diagnosis.strategy import NORM
    from accellog.calibrate.model.effects import HANDHELD_START
    from accellog.calibrate.observe.detected_holds import detect_holds, norm_obs
    from accellog.store.source import open_source

    data = datas[0]
    helds = [norm_obs(open_source(h, what="--heldout").whole()) for h in heldout]
    start = model if model and model != "model3" else HANDHELD_START
    with small_problem_threads():
        obs, det = detect_holds(data)
        parts = [obs] + [detect_holds(d)[0] for d in datas[1:]]
        obs = concat_obs(parts) if len(parts) > 1 else obs
        found = Discovery(start=start, detection=det, obs=obs)
        discover(obs, start, heldout=helds, max_steps=max_steps, effects_file=effects_file,
                 sessions=parts if len(parts) > 1 else None, strategy=NORM, found=found)  # fmt: skip
    found.ladder = ladder_rows(data, obs, steps_for(found), heldout=helds, static_test=test,
                               effects_file=effects_file, at_s=at_s, gyro=False, strategy=NORM,
                               scatter=found.scatter, sessions=parts, per_session=found.ladder_loso)  # fmt: skip
    if output is not None:
        from accellog.flows.stages import run_fit

        # the full orientation-free fit: gyro from the detected intervals and the rotations between them
        # several sessions: the windows of all of them (the gyro: the first session's)
        pooled = found.obs if len(datas) > 1 else None
        cal = run_fit(
            data, found.start, add=found.added, effects_file=effects_file, orientation_free=True, obs=pooled
        ).cal
        with_notes(cal, found).save(output)
    if rrd is not None:
        from accellog.present.detection_views import log_detection
        from accellog.present.rrd.recording import RunRecording
        from accellog.present.views import log_session

        assert found.detection is not None  # a hand-held search: its intervals
        with RunRecording(f"save:{rrd}") as rec:
            log_session(rec, data)
            log_detection(rec, found.detection)
            rec.log_ladder(found.ladder)
            log_story(rec, found, found.ladder, found.obs, found.diagnoses[-1].fit)
    return WorkbenchOutcome(
        str(session),
        found,
        found.ladder,
        None if output is None else str(output),
        ladder_loso=found.ladder_loso,
    )
