"""The model workbench loop: diagnose, add the significant effect that predicts unseen data best
(accellog.calibrate.diagnosis.choose), refit, until no candidate improves out of sample; then the ladder of model-building steps, each judged on the calibration
data (chi^2/dof), on a held-out session (residual RMS vs its noise floor) and on a static test
(|displacement| after 60 s).

    steps: model1 -> model2 -> model3 -> model3 + e1 -> model3 + e1 + e2 ...

``discover`` never adds an effect diagnose does not find significant and identifiable, so a clean
session stops at the start model; it never says "nothing is missing" when the held-out chi2/dof
exceeds HELDOUT_OK, and it names effects the data cannot tell apart instead of choosing silently.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from accellog.core.session import ObsTable, Session

if TYPE_CHECKING:
    from accellog.calibrate.diagnosis.ladder import LadderRow
    from accellog.calibrate.diagnosis.strategy import Strategy

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
    (names for --add), and the final verdict that uses all the evidence."""

    start: str
    diagnoses: list = field(default_factory=list)
    choices: list = field(default_factory=list)
    added: list[str] = field(default_factory=list)
    heldout: dict | None = None
    """Held-out statistics of the final model (heldout_rms_g, heldout_noise_g, heldout_chi2_dof)."""
    verdict: str = ""
    advice: list[str] = field(default_factory=list)
    undecided: list[list[str]] = field(default_factory=list)
    """Groups of effects the data cannot tell apart (first: the one added)."""
    dropped: list[dict] = field(default_factory=list)
    """Effects added and then dropped: {effect, why} (a backward step, or a proxy that did not
    make the model transfer: accellog.flows.workbench_prune)."""
    loso: list[dict | None] | None = None
    """With several calibration sessions: the final model's held-out statistics per left-out session."""
    yardstick: dict | None = None
    """The between-hold scatter every model was judged with held out (variance.yardstick: from
    replicate holds of the richest model, or its residual), with its source."""
    scatter: object = field(default=None, repr=False)
    """The yardstick itself (variance.HoldScatter), for the ladder's held-out columns."""
    final_diagnosis: object = field(default=None, repr=False)
    """The diagnosis of the final model when pruning made it another than the last step's."""
    trail: list = field(default_factory=list)
    """Every model the search tried, in order, with its held-out residual on the yardstick
    (accellog.flows.workbench_trail.TrailStep: kept, dropped, tied, rejected, removed)."""

    @property
    def final_model(self) -> str:
        return "+".join([self.start, *self.added])

    @property
    def decided(self) -> bool:
        return not self.undecided

    @property
    def transfers(self) -> bool | None:
        """The final model transfers (None without a held-out session): see held_out_ok."""
        return None if self.heldout is None else held_out_ok(self.heldout)

    def to_json(self) -> dict:
        """JSON-able summary (the workbench's --json keys besides session and ladder)."""
        return {
            "start": self.start,
            "added": list(self.added),
            "final_model": self.final_model,
            "verdict": self.verdict,
            "decided": self.decided,
            "undecided": [list(u) for u in self.undecided],
            "transfers": self.transfers,
            "heldout": self.heldout,
            "verdicts": [d.verdict for d in self.diagnoses],
            "steps": [c.to_dict() for c in self.choices],
            "advice": list(self.advice),
            "dropped": [dict(d) for d in self.dropped],
            "yardstick": self.yardstick,
            "trail": [t.to_dict() for t in self.trail],
            **({} if self.loso is None else {"heldout_per_session": self.loso}),
        }


def discover(
    obs: ObsTable,
    start: str = "model3",
    *,
    heldout: Sequence[ObsTable] | ObsTable | None = None,
    max_steps: int = 4,
    effects_file: str | Path | None = None,
    host_time: tuple[np.ndarray, np.ndarray] | None = None,
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
    Discovery to fill (a HandheldDiscovery), default a new one."""
    from accellog.calibrate.diagnosis.strategy import LABELLED

    held = [heldout] if isinstance(heldout, ObsTable) else list(heldout or [])
    found = found if found is not None else Discovery(start=start)
    with small_problem_threads():
        _search(found, obs, held, list(sessions or []), strategy or LABELLED, max_steps, effects_file, host_time,
                on_step)  # fmt: skip
    found.verdict, found.advice = final_verdict(found, strategy or LABELLED)
    return found


def small_problem_threads():
    """Single-threaded BLAS for the workbench's many small (~1000 x 20) least-squares problems:
    threads only add overhead there, and oversubscribe a loaded machine (10x slower at load 12)."""
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=1, user_api="blas")


def _search(out: Discovery, obs, held, parts, strategy, max_steps, effects_file, host_time, on_step) -> None:
    """discover's forward loop, backward steps, held-out statistics and proxies (module doc)."""
    from accellog.calibrate.diagnosis.diagnose import default_candidates
    from accellog.calibrate.model.compose import build_model
    from accellog.calibrate.model.variance import yardstick
    from accellog.flows import workbench_trail as trail
    from accellog.flows.workbench_prune import backward_step

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
        ch = d.choice if len(out.added) < max_steps else None
        trail.note_start(out, ch)
        if ch is not None:
            out.choices.append(ch)
        if ch is None or ch.chosen is None or ch.chosen in out.added:
            trail.note_rejected(out, ch)
            break
        if ch.undecided:
            out.undecided.append([ch.chosen, *ch.undecided])
        out.added.append(ch.chosen)
        trail.note_added(out, ch)
        model = model.with_terms([ch.chosen])
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
            if stats is not None and out.yardstick["source"] != "replicates":
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
    """workbench_prune.prune on the models the search walked through, each proxy removed also a
    trail row; then every trail row's held-out statistics (judged: on the common yardstick)."""
    from accellog.flows.workbench_prune import prune
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
    proxies = [x["effect"] for x in getattr(found, "dropped", []) if x.get("proxy")]
    d = found.final_diagnosis or found.diagnoses[-1]  # the final model's (after pruning)
    parts, extra, held_ok = evidence_parts(found, norm=norm, diagnosis=d)
    if norm:
        if not parts:
            return d.verdict.rstrip(".") + held_ok + ".", extra
        head = f"{d.model.name}: norm chi2/dof {d.fit.chi2_dof:.3g} on the calibration session"
        return f"{head}; " + "; ".join(parts) + held_ok + ".", extra
    where = "the calibration session" + ("s" if getattr(found, "loso", None) else "")
    fit = f"{d.model.name}: chi2/dof {d.fit.chi2_dof:.3g} on {where}"
    advice = [a for a in d.advice if not any(e in a for e in proxies)] + extra
    if not parts and not d.missing:
        return f"{fit}: the model fits to the noise floor; nothing is missing{held_ok}.", advice
    if not parts:
        return d.verdict + held_ok, advice
    return f"{fit}; " + "; ".join(parts) + held_ok + ".", advice


def evidence_parts(found, norm: str, diagnosis=None) -> tuple[list[str], list[str], str]:
    """(verdict parts, advice, held-out suffix) of a discovery's ties, refusals, dropped effects and
    held-out result, shared by the labelled and hand-held workbenches (norm = "norm " names the
    gravity-norm residual; diagnosis: that of the final model, default the last)."""
    from accellog.flows.workbench_prune import no_library_effect

    d = diagnosis if diagnosis is not None else found.diagnoses[-1]
    dropped = list(getattr(found, "dropped", []))
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
        parts.append(no_library_effect(d, proxies, norm, getattr(found, "obs", None)))
    held_ok = ""
    if found.transfers:  # a model that misses something transfers only within its own scatter
        held_ok = f" (held-out {norm}chi2/dof {h['heldout_chi2_dof']:.3g}: " + (
            "within the calibration's own scatter)" if d.missing else "it transfers)"
        )
    return parts, advice, held_ok


def ladder_rows(
    calibration: Session,
    obs: ObsTable,
    steps: Sequence[tuple[str, list[str]]],
    *,
    heldout: ObsTable | None = None,
    static_test: Session | None = None,
    effects_file: str | Path | None = None,
    at_s: float = 60.0,
    gyro: bool = True,
    scatter=None,
) -> list[LadderRow]:
    """Fit each step (preset, added effects) and judge it: chi2/dof and RMS on the calibration
    windows, held-out residual RMS and noise floor (g) and predictive chi2/dof (on scatter: the
    search's one yardstick), |displacement| of the static test at at_s (m). Each row keeps its
    FitOutcome in .fit (not JSON); gyro: calibrate the gyro with the last step (for the file)."""
    with small_problem_threads():
        return _ladder_rows(calibration, obs, steps, heldout, static_test, effects_file, at_s, gyro, scatter)


def _ladder_rows(calibration, obs, steps, heldout, static_test, effects_file, at_s, gyro, scatter=None):
    from accellog.calibrate.diagnosis.ladder import ladder_row
    from accellog.flows.stages import run_fit

    rows = []
    for i, (preset, add) in enumerate(steps):
        fo = run_fit(
            calibration,
            preset,
            add=list(add),
            effects_file=effects_file,
            obs=obs,
            gyro=gyro and i == len(steps) - 1,
        )
        row = ladder_row(fo.fit, added=add, heldout=heldout, fit=fo, scatter=scatter)
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
    """model1, model2, the start model, then one step per added effect."""
    steps = [(p, []) for p in BASE_STEPS if p != discovery.start]
    steps.append((discovery.start, []))
    for k in range(1, len(discovery.added) + 1):
        steps.append((discovery.start, discovery.added[:k]))
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
