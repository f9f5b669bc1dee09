"""The workbench on a hand-held session (no pose labels): the detected static intervals
(accellog.calibrate.diagnosis.handheld.detect_holds) and the orientation-free gravity-norm residual

    e_r = |correct(a'_r)| - g

replace the labelled poses. Loop: diagnose_handheld, add a significant effect, refit, until nothing
the norm can identify is significant (or max_steps). Which effect: with held-out sessions the one
that predicts their gravity norm best (accellog.calibrate.diagnosis.norm_transfer, chosen as the labelled
workbench chooses: accellog.calibrate.diagnosis.choose; ties and near-collinear candidates are named); with
several calibration sessions by leaving one out; with one session by blocks of its temperature
range and of time (accellog.calibrate.diagnosis.norm_transfer.norm_blocked_scores). Then the ladder start -> + each found effect, judged on the norm
(chi^2/dof, RMS in g), on the held-out norm, and, with a static test, by its |displacement| at at_s
(m). The verdict never says "nothing is missing" while the held-out norm chi2/dof exceeds
HELDOUT_OK. What the norm cannot identify (a frame rotation, fixture tilt, the clock, effects the
data do not excite) is said in `cannot_identify`, never guessed.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from accellog.core.jsonio import JsonResult
from accellog.core.session import Session
from accellog.flows.workbench import HELDOUT_OK, evidence_parts

if TYPE_CHECKING:
    from accellog.calibrate.diagnosis.choose import StepChoice
    from accellog.calibrate.diagnosis.diagnose import Diagnosis
    from accellog.calibrate.diagnosis.handheld import Detection
    from accellog.calibrate.diagnosis.ladder import LadderRow
    from accellog.core.session import ObsTable


@dataclass
class HandheldDiscovery(JsonResult):
    """What the hand-held loop found: detected intervals, one diagnosis per step, the effects added
    (names for --add), the ladder, and what the gravity norm cannot identify."""

    start: str
    detection: Detection
    obs: ObsTable = field(repr=False)
    diagnoses: list[Diagnosis] = field(default_factory=list)
    added: list[str] = field(default_factory=list)
    ladder: list[LadderRow] = field(default_factory=list)
    choices: list[StepChoice] = field(default_factory=list)
    """Out-of-sample choice of each step (held-out sessions, leave one session out, or blocks)."""
    heldout: dict | None = None
    """Held-out norm statistics of the final model (heldout_rms_g, heldout_noise_g, heldout_chi2_dof)."""
    undecided: list[list[str]] = field(default_factory=list)
    """Groups of effects the data cannot tell apart (first: the one added)."""
    dropped: list[dict] = field(default_factory=list)
    """Effects added and then dropped: {effect, why} (accellog.flows.workbench_prune)."""
    verdict: str = ""
    advice: list[str] = field(default_factory=list)
    loso: list[dict | None] | None = None
    """With several calibration sessions: the final model's held-out statistics per left-out session."""
    ladder_loso: list[list[dict | None]] = field(default_factory=list)
    """With several calibration sessions: per ladder row, its held-out statistics per left-out session."""

    @property
    def final_model(self) -> str:
        return "+".join([self.start, *self.added])

    @property
    def decided(self) -> bool:
        return not self.undecided

    @property
    def transfers(self) -> bool | None:
        """Held-out norm chi2/dof of the final model <= HELDOUT_OK (None without a held-out session)."""
        return None if self.heldout is None else bool(self.heldout["heldout_chi2_dof"] <= HELDOUT_OK)

    @property
    def cannot_identify(self) -> list[str]:
        """The last diagnosis's statements of what the norm (or this data) cannot identify."""
        return [a for a in self.diagnoses[-1].advice if not a.startswith("refit with")]

    def to_dict(self) -> dict:
        """workbench --json on a hand-held session (the labelled workbench's keys where they apply)."""
        return {
            "handheld": True,
            "start": self.start,
            "added": list(self.added),
            "final_model": self.final_model,
            "verdict": self.verdict,
            "verdicts": [d.verdict for d in self.diagnoses],
            "decided": self.decided,
            "undecided": [list(u) for u in self.undecided],
            "transfers": self.transfers,
            "heldout": self.heldout,
            "steps": [c.to_dict() for c in self.choices],
            "advice": list(self.advice),
            "dropped": [dict(d) for d in self.dropped],
            **({} if self.loso is None else {"heldout_per_session": self.loso}),
            "cannot_identify": self.cannot_identify,
            "detected": self.detection.to_dict(),
            "ladder": [r.to_dict() for r in self.ladder],
        }


def discover_handheld(
    session: Session,
    start: str | None = None,
    *,
    heldout: Sequence[ObsTable] = (),
    window_s: float = 2.0,
    detect_window_s: float = 1.0,
    threshold: float | None = None,
    max_steps: int = 4,
    effects_file: str | Path | None = None,
    static_test: Session | None = None,
    at_s: float = 60.0,
    more_sessions: Sequence[Session] = (),
) -> HandheldDiscovery:
    """Detect the static intervals of an unlabelled session, then diagnose / add / refit on the
    gravity norm (start: HANDHELD_START by default; model3's cross_axis is not identifiable here).
    heldout: windows of other sessions of the same sensor (calibrate.handheld.norm_obs): each step
    adds the candidate that predicts their gravity norm best, and only if it does. more_sessions:
    further calibration sessions: the fit uses all of them and candidates are judged by leaving
    one session out (calibrate.loso); `detection` is the first session's."""
    from accellog.calibrate.diagnosis.handheld import HANDHELD_START, detect_holds
    from accellog.calibrate.diagnosis.loso import concat_obs
    from accellog.flows.workbench import small_problem_threads

    start = start or HANDHELD_START
    with small_problem_threads():
        obs, det = detect_holds(session, window_s=detect_window_s, threshold=threshold, obs_window_s=window_s)
        parts = [obs] + [
            detect_holds(s, window_s=detect_window_s, threshold=threshold, obs_window_s=window_s)[0]
            for s in more_sessions
        ]
        obs = concat_obs(parts) if len(parts) > 1 else obs
        found = HandheldDiscovery(start=start, detection=det, obs=obs)
        _loop(found, list(heldout), max_steps, effects_file, parts)
        found.ladder = _ladder(
            session,
            obs,
            start,
            found.added,
            effects_file,
            static_test,
            at_s,
            heldout,
            parts,
            found.ladder_loso,
        )
    found.verdict, found.advice = _final_verdict(found)
    return found


def _loop(found: HandheldDiscovery, held: list, max_steps: int, effects_file, parts: list) -> None:
    from accellog.calibrate.diagnosis.diagnose import default_candidates
    from accellog.calibrate.diagnosis.handheld import diagnose_handheld, norm_choice
    from accellog.calibrate.diagnosis.loso import loso_stats, mean_stats
    from accellog.calibrate.diagnosis.norm_transfer import norm_heldout_stats
    from accellog.calibrate.model.compose import build_model
    from accellog.calibrate.model.fit import fit_orientation_free
    from accellog.flows.workbench_prune import backward_step, proxy_stats

    gone: set[str] = set()
    scores = _norm_scores(found.obs, held, parts)
    while True:
        m = build_model(found.start, add=found.added, effects_file=effects_file)
        d = diagnose_handheld(found.obs, m, candidates=[c for c in default_candidates(m) if c not in gone])
        found.diagnoses.append(d)
        if len(found.added) >= max_steps:
            break
        ch = norm_choice(d, found.obs, held, sessions=parts)
        found.choices.append(ch)
        chosen = ch.chosen
        if chosen is not None and ch.undecided:
            found.undecided.append([chosen, *ch.undecided])
        if chosen is None or chosen in found.added:
            break
        found.added.append(chosen)
        full = d.fits.get(chosen)
        while (
            drop := backward_step(
                found.added, found.start, effects_file, found.obs, scores, full, fit_orientation_free
            )
        ) is not None:
            found.added.remove(drop[0])
            found.dropped.append({"effect": drop[0], "why": drop[1]})
            gone.add(drop[0])
            full = None

    def stats_of(name: str) -> dict | None:
        model = build_model(name, effects_file=effects_file)
        if len(parts) > 1:
            found.loso = loso_stats(parts, model, fit_orientation_free, _stats1)
            return mean_stats(found.loso)
        return norm_heldout_stats(fit_orientation_free(found.obs, model), held) if held else None

    found.heldout = stats_of(found.final_model)
    found.dropped += [{"effect": e, "why": w, "proxy": True} for e, w in proxy_stats(found, stats_of)]
    # a tie is resolved when every alternative ended up in the model too (or its choice was dropped)
    found.undecided = [
        g
        for g in ([g[0], *[e for e in g[1:] if e not in found.added]] for g in found.undecided)
        if len(g) > 1 and g[0] in found.added
    ]


def _norm_scores(obs, held, parts):
    """Out-of-sample gravity-norm scores of fits by name, with norm_choice's evidence."""
    from accellog.calibrate.diagnosis.loso import loso_score
    from accellog.calibrate.diagnosis.norm_transfer import norm_blocked_scores, norm_heldout_score
    from accellog.calibrate.model.fit import fit_orientation_free

    def scores(fits):
        if len(parts) > 1:
            return {
                n: loso_score(parts, r.model, fit_orientation_free, norm_heldout_score)
                for n, r in fits.items()
            }
        if not held:
            return norm_blocked_scores(fits, obs)
        return {n: norm_heldout_score(r, held) for n, r in fits.items()}

    return scores


def _stats1(res, obs) -> dict[str, float]:
    from accellog.calibrate.diagnosis.norm_transfer import norm_heldout_stats

    return norm_heldout_stats(res, [obs])


def _final_verdict(found: HandheldDiscovery) -> tuple[str, list[str]]:
    """One verdict from the last diagnosis, the held-out norm and the ties (as the labelled
    workbench's flows.workbench.final_verdict)."""
    proxies = [x["effect"] for x in found.dropped if x.get("proxy")]
    d = found.diagnoses[0] if proxies else found.diagnoses[-1]  # proxies dropped: the start model
    parts, advice, held_ok = evidence_parts(found, norm="norm ", diagnosis=d)
    if not parts:
        return d.verdict.rstrip(".") + held_ok + ".", advice
    head = f"{d.model.name}: norm chi2/dof {d.fit.chi2_dof:.3g} on the calibration session"
    return f"{head}; " + "; ".join(parts) + held_ok + ".", advice


def _ladder(
    session, obs, start, added, effects_file, static_test, at_s, heldout=(), parts=(), row_loso=None
) -> list[LadderRow]:
    """start, start + e1, start + e1 + e2, ... fitted orientation-free on the detected windows;
    held-out norm statistics (mean over the held-out sessions, or with several calibration sessions
    over the left-out sessions; then each row's per-session statistics are appended to row_loso)."""
    from accellog.calibrate.diagnosis.ladder import ladder_row
    from accellog.calibrate.diagnosis.loso import loso_stats, mean_stats
    from accellog.calibrate.diagnosis.norm_transfer import norm_heldout_stats
    from accellog.calibrate.model.fit import fit_orientation_free
    from accellog.flows.stages import run_fit
    from accellog.flows.workbench import add_static_drift

    rows = []
    for k in range(len(added) + 1):
        fo = run_fit(
            session,
            start,
            add=added[:k],
            effects_file=effects_file,
            orientation_free=True,
            obs=obs,
            gyro=False,
        )
        row = ladder_row(fo.fit, added=added[:k], fit=fo)
        if len(parts) > 1:
            per = loso_stats(parts, fo.fit.model, fit_orientation_free, _stats1)
            row_loso.append(per)
            for key, v in mean_stats(per).items():
                setattr(row, key, v)
        elif heldout:
            for key, v in norm_heldout_stats(fo.fit, heldout).items():
                setattr(row, key, v)
        if static_test is not None:
            add_static_drift(row, static_test, at_s)
        rows.append(row)
    return rows
