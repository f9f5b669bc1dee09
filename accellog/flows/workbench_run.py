"""`accellog workbench` as one library call: the discovery loop and the model ladder on a session.

A labelled session goes to accellog.flows.workbench (diagnose, add what transfers, refit; the
ladder model1 -> model2 -> model3 -> + each found effect, judged on held-out data and a static
test); a session without pose labels (hand-held) to accellog.flows.handheld_workbench (detected
static intervals, gravity-norm residual). Optionally the final model's calibration file (-o) and a
Rerun recording (--rrd). The result is typed (WorkbenchOutcome); the CLI only presents it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from accellog.core.errors import InputError
from accellog.core.jsonio import JsonResult

if TYPE_CHECKING:
    from accellog.calibrate.diagnosis.ladder import LadderRow
    from accellog.flows.handheld_workbench import HandheldDiscovery
    from accellog.flows.workbench import Discovery


@dataclass
class WorkbenchOutcome(JsonResult):
    """One workbench run: what the loop found (Discovery, or HandheldDiscovery for an unlabelled
    session), the ladder, and the calibration file written (if any)."""

    session: str
    found: Discovery | HandheldDiscovery
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
        return bool(getattr(self.found, "detection", None) is not None)

    @property
    def ok(self) -> bool:
        """The loop decided, the final model transfers (or no held-out session) and nothing is missing."""
        f = self.found
        return f.decided and f.transfers is not False and not f.diagnoses[-1].missing

    def to_dict(self) -> dict:
        """workbench --json: session, the loop's keys and the ladder; with several calibration
        sessions also `sessions` and `leave_one_session_out` (loso_dict)."""
        if self.handheld:
            out = {"session": self.session, **self.found.to_dict()}
        else:
            out = {
                "session": self.session,
                **self.found.to_json(),
                "ladder": [r.to_dict() for r in self.ladder],
            }
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
    from accellog.flows.workbench import discover, ladder_rows, steps_for
    from accellog.store.source import open_source

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
        host = (data.t_s, data.host_time_s)
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
    rows = ladder_rows(
        data,
        obs,
        steps_for(found),
        heldout=helds[0] if helds else None,
        static_test=test,
        effects_file=effects_file,
        at_s=at_s,
        gyro=output is not None or rrd is not None,  # the gyro goes into the calibration file / .rrd
        scatter=found.scatter,
    )
    ladder_loso = _loso_rows(rows, parts, found.scatter) if len(parts) > 1 else []
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
    notes += [
        f"workbench: {d['effect']} not written: {d['why']}"
        for d in getattr(found, "dropped", [])
        if d.get("proxy")
    ]
    if not notes:
        return cal
    cal.fit = dataclasses.replace(cal.fit, warnings=(*(cal.fit.warnings or ()), *dict.fromkeys(notes)))
    return cal


def _loso_rows(rows, parts, scatter=None) -> list[list[dict | None]]:
    """Each ladder row's model left-one-session-out: per session its held-out statistics; the
    row's heldout_* columns become their mean."""
    from accellog.calibrate.diagnosis.loso import loso_stats, mean_stats
    from accellog.calibrate.diagnosis.transfer import predictive_stats
    from accellog.calibrate.model.fit import fit_model

    out = []
    for r in rows:
        per = loso_stats(
            parts,
            r.fit.fit.model,
            fit_model,
            lambda res, o: predictive_stats(res, o, norm=False, scatter=scatter),
        )
        for k, v in mean_stats(per).items():
            setattr(r, k, v)
        out.append(per)
    return out


def _write_rrd(rrd, data, found, rows, obs) -> None:
    from accellog.flows.workbench import log_ladder
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
    """The workbench on an unlabelled session (accellog.flows.handheld_workbench); held-out sessions
    (labelled or not) are judged on their gravity norm."""
    from accellog.calibrate.observe.detected_holds import norm_obs
    from accellog.flows.handheld_workbench import discover_handheld
    from accellog.store.source import open_source

    data = datas[0]
    helds = [norm_obs(open_source(h, what="--heldout").whole()) for h in heldout]
    start = None if model == "model3" else model  # model3's cross_axis is not identifiable here
    found = discover_handheld(
        data,
        start,
        heldout=helds,
        max_steps=max_steps,
        effects_file=effects_file,
        static_test=test,
        at_s=at_s,
        more_sessions=datas[1:],
    )
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
