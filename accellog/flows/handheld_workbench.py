"""The workbench on a hand-held session (no pose labels): the detected static intervals
(accellog.calibrate.handheld.detect_holds) and the orientation-free gravity-norm residual

    e_r = |correct(a'_r)| - g

replace the labelled poses. Loop: diagnose_handheld, add the significant effect with the lowest
dBIC, refit, until nothing the norm can identify is significant (or max_steps). Then the ladder
start -> + each found effect, judged on the norm (chi^2/dof, RMS in g) and, with a static test, by
its |displacement| at at_s (m). What the norm cannot identify (a frame rotation, fixture tilt, the
clock, effects the data do not excite) is said in `cannot_identify`, never guessed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from accellog.core.jsonio import JsonResult
from accellog.core.session import Session

if TYPE_CHECKING:
    from accellog.calibrate.diagnose import Diagnosis
    from accellog.calibrate.handheld import Detection
    from accellog.calibrate.ladder import LadderRow
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

    @property
    def final_model(self) -> str:
        return self.diagnoses[-1].model.name

    @property
    def verdict(self) -> str:
        return self.diagnoses[-1].verdict

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
            "cannot_identify": self.cannot_identify,
            "detected": self.detection.to_dict(),
            "ladder": [r.to_dict() for r in self.ladder],
        }


def discover_handheld(
    session: Session,
    start: str | None = None,
    *,
    window_s: float = 2.0,
    detect_window_s: float = 1.0,
    threshold: float | None = None,
    max_steps: int = 4,
    effects_file: str | Path | None = None,
    static_test: Session | None = None,
    at_s: float = 60.0,
) -> HandheldDiscovery:
    """Detect the static intervals of an unlabelled session, then diagnose / add / refit on the
    gravity norm (start: HANDHELD_START by default; model3's cross_axis is not identifiable here)."""
    from accellog.calibrate.handheld import HANDHELD_START, detect_holds, diagnose_handheld
    from accellog.calibrate.model import build_model
    from accellog.flows.workbench import small_problem_threads

    start = start or HANDHELD_START
    with small_problem_threads():
        obs, det = detect_holds(session, window_s=detect_window_s, threshold=threshold, obs_window_s=window_s)
        found = HandheldDiscovery(start=start, detection=det, obs=obs)
        while True:
            m = build_model(start, add=found.added, effects_file=effects_file)
            d = diagnose_handheld(obs, m)
            found.diagnoses.append(d)
            sig = [r for r in d.candidates if r.get("significant")]
            if not sig or len(found.added) >= max_steps:
                break
            found.added.append(sig[0]["effect"])
        found.ladder = _ladder(session, obs, start, found.added, effects_file, static_test, at_s)
    return found


def _ladder(session, obs, start, added, effects_file, static_test, at_s) -> list[LadderRow]:
    """start, start + e1, start + e1 + e2, ... fitted orientation-free on the detected windows."""
    from accellog.calibrate.ladder import ladder_row
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
        if static_test is not None:
            add_static_drift(row, static_test, at_s)
        rows.append(row)
    return rows
