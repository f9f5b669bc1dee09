"""The workbench on a hand-held session (no pose labels): the detected static intervals
(accellog.calibrate.observe.detected_holds.detect_holds) and the orientation-free gravity-norm residual

    e_r = |correct(a'_r)| - g

replace the labelled poses. The loop is the workbench's one (flows.workbench.discover) with the
gravity-norm strategy (calibrate.diagnosis.strategy.NORM: diagnose_handheld, the norm's held-out,
leave-one-session-out and blocked scores, its collinearity). Then the ladder start -> + each found
effect, judged on the norm
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
from accellog.flows.workbench import Discovery, discover, small_problem_threads

if TYPE_CHECKING:
    from accellog.calibrate.diagnosis.ladder import LadderRow
    from accellog.calibrate.observe.detected_holds import Detection
    from accellog.core.session import ObsTable


@dataclass
class HandheldDiscovery(JsonResult, Discovery):
    """What the hand-held loop found (a Discovery on the gravity norm) with the detected intervals,
    the ladder, and what the gravity norm cannot identify."""

    detection: Detection | None = None
    obs: ObsTable | None = field(default=None, repr=False)
    ladder: list[LadderRow] = field(default_factory=list)
    ladder_loso: list[list[dict | None]] = field(default_factory=list)
    """With several calibration sessions: per ladder row, its held-out statistics per left-out session."""

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
            "trail": [t.to_dict() for t in self.trail],
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
    """Detect the static intervals of an unlabelled session, then the workbench's loop
    (flows.workbench.discover) on the gravity norm (calibrate.diagnosis.strategy.NORM; start:
    HANDHELD_START by default: model3's cross_axis is not identifiable here). heldout: windows of
    other sessions of the same sensor (calibrate.observe.detected_holds.norm_obs): each step adds the candidate
    that predicts their gravity norm best, and only if it does. more_sessions: further calibration
    sessions: the fit uses all of them and candidates are judged by leaving one session out
    (calibrate.loso); `detection` is the first session's."""
    from accellog.calibrate.diagnosis.loso import concat_obs
    from accellog.calibrate.diagnosis.strategy import NORM
    from accellog.calibrate.model.effects import HANDHELD_START
    from accellog.calibrate.observe.detected_holds import detect_holds

    start = start or HANDHELD_START
    with small_problem_threads():
        obs, det = detect_holds(session, window_s=detect_window_s, threshold=threshold, obs_window_s=window_s)
        parts = [obs] + [
            detect_holds(s, window_s=detect_window_s, threshold=threshold, obs_window_s=window_s)[0]
            for s in more_sessions
        ]
        obs = concat_obs(parts) if len(parts) > 1 else obs
        found = HandheldDiscovery(start=start, detection=det, obs=obs)
        discover(obs, start, heldout=list(heldout), max_steps=max_steps, effects_file=effects_file,
                 sessions=parts if len(parts) > 1 else None, strategy=NORM, found=found)  # fmt: skip
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
    return found


def _ladder(
    session,
    obs,
    start,
    added,
    effects_file,
    static_test,
    at_s,
    heldout=(),
    parts=(),
    row_loso=None,
    scatter=None,
) -> list[LadderRow]:
    """start, start + e1, start + e1 + e2, ... fitted orientation-free on the detected windows;
    held-out norm statistics (mean over the held-out sessions, or with several calibration sessions
    over the left-out sessions; then each row's per-session statistics are appended to row_loso)."""
    from accellog.calibrate.diagnosis.ladder import ladder_row
    from accellog.calibrate.diagnosis.loso import loso_stats, mean_stats
    from accellog.calibrate.diagnosis.strategy import NORM
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
            per = loso_stats(
                parts, fo.fit.model, fit_orientation_free, lambda r, o: NORM.heldout_stats(r, o, scatter)
            )
            row_loso.append(per)
            for key, v in mean_stats(per).items():
                setattr(row, key, v)
        elif heldout:
            for key, v in NORM.mean_heldout_stats(fo.fit, heldout, scatter).items():
                setattr(row, key, v)
        if static_test is not None:
            add_static_drift(row, static_test, at_s)
        rows.append(row)
    return rows
