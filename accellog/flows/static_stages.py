"""The static-session stages behind `segment`, `evaluate` and `integrate`, each returning a typed result.

- `run_segment(session)`           -> SegmentResult (per-pose statistics, windowed observations)
- `run_evaluate_report(test, cals)` -> EvaluationReport: one static hold (the seed's tables 4 and 5)
                                      or, for a session with several labelled holds, hold by hold
- `run_integrate(session, cal)`     -> Integration: v(t), d(t) of a static session (m/s, m)
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from accellog.calibrate.calfile.calibration import Calibration, as_calibration
from accellog.calibrate.observe.obs_file import obs_to_dict
from accellog.calibrate.observe.segment import PoseStats, observations, pose_stats
from accellog.calibrate.observe.stream_segment import stream_observations
from accellog.core.errors import InputError
from accellog.core.jsonio import JsonResult
from accellog.core.numfmt import format_rows
from accellog.core.session import ObsTable, Session
from accellog.flows.stages import load_input, run_evaluate
from accellog.flows.static_input import run_on_blocks
from accellog.flows.stream_input import StreamedSession, can_stream, open_streamed
from accellog.navigate.blocks import Blocks, file_blocks
from accellog.navigate.evaluate import (
    Evaluation,
    PoseEvaluation,
    Target,
    evaluate_blocks,
    evaluate_pose_obs,
    targets,
)
from accellog.present import tables, views
from accellog.present.residual_views import log_panels, log_residuals_vs_drivers, panels
from accellog.present.rrd.offload import open_recording
from accellog.store.atomic import atomic_output

if TYPE_CHECKING:  # the hand-held path (scipy.stats, ~60 MB and ~0.9 s of imports) loads when used
    from accellog.navigate.handheld_evaluate import HandheldEvaluation


def _session_input(path: str | os.PathLike, what: str) -> Session:
    data = load_input(path)
    if not isinstance(data, Session):
        raise InputError(f"{what} needs a recorded session (samples), not a pose table", where=str(path))
    return data


@dataclass
class SegmentResult(JsonResult):
    """Per-pose statistics and the windowed observation table of one session."""

    session: Session | StreamedSession
    stats: list[PoseStats]
    obs: ObsTable
    window_s: float

    def obs_dict(self) -> dict:
        return obs_to_dict(self.obs)

    def to_dict(self, output: str = "") -> dict:
        return {"poses": [p.to_dict() for p in self.stats], "n_observations": self.obs.n, "output": output}


def run_segment(path: str | os.PathLike, *, window_s: float = 2.0, trim_s: float = 0.5) -> SegmentResult:
    """Statistics of every labelled hold and observations of ~window_s (s), trim_s (s) dropped at both ends."""
    if can_stream(path):  # an MCAP session: chunk by chunk, bounded memory
        s = open_streamed(path, window_s=window_s, trim_s=trim_s, stats=True)
        if s is not None:
            return SegmentResult(s, s.stats or [], s.obs, window_s)
    data = _session_input(path, "segment")
    stats = pose_stats(data, trim_s=trim_s)
    return SegmentResult(data, stats, observations(data, window_s=window_s, trim_s=trim_s), window_s)


@dataclass
class EvaluationReport(JsonResult):
    """`evaluate` of one or more calibrations: ``single`` (one static hold: raw first, then each
    calibration) or ``poses`` (a session with several labelled holds, evaluated hold by hold)."""

    data: Session | ObsTable | StreamedSession
    cals: list[Calibration]
    labels: list[str] | None
    at_s: float
    single: list[Evaluation] = field(default_factory=list)
    poses: list[PoseEvaluation] = field(default_factory=list)
    obs: ObsTable | None = None
    """The observation windows the pose evaluations judge (multi-pose and hand-held sessions)."""
    handheld: list[HandheldEvaluation] = field(default_factory=list)
    """Unlabelled sessions that move: per detected interval, the gravity-norm residual."""

    @property
    def kind(self) -> str:
        return "poses" if self.poses else "handheld" if self.handheld else "single"

    def to_dict(self) -> dict:
        if self.handheld:
            from accellog.navigate.handheld_evaluate import CANNOT_JUDGE

            return {
                "kind": "handheld",
                "raw": self.handheld[0].to_dict(),
                "calibrated": [h.to_dict() for h in self.handheld[1:]],
                "cannot_judge": CANNOT_JUDGE,
            }
        if self.poses:
            return {
                "kind": "poses",
                "raw": self.poses[0].to_dict(),
                "calibrated": [p.to_dict() for p in self.poses[1:]],
            }
        return {"raw": self.single[0].to_dict(), "calibrated": [e.to_dict() for e in self.single[1:]]}

    def calibrations_by_label(self) -> dict[str, Calibration]:
        rows = self.poses[1:] if self.poses else self.handheld[1:] if self.handheld else self.single[1:]
        return dict(zip(self.labels or [r.label for r in rows], self.cals, strict=True))

    def write_rrd(self, path: str | Path) -> None:
        """The session (raw and calibrated) and the evaluation (tracks, or per-pose residual tables)."""

        with open_recording(f"save:{path}") as rec:
            if isinstance(self.data, Session):
                views.log_session(rec, self.data, calibrations=self.calibrations_by_label())
            if self.poses:
                md = "\n".join(views.table_markdown(tables.pose_eval_table(p)) for p in self.poses)
                passes = [t for t in (tables.pass_eval_table(p) for p in self.poses) if t is not None]
                md += "".join("\n" + views.table_markdown(t) for t in passes)
                md += "".join(f"\n- {f}" for p in self.poses for f in p.flags)
                rec.log_document("results/poses", md)
                fits = {p.label: _WindowResiduals(p.window_resid_g) for p in self.poses}
                log_residuals_vs_drivers(rec, self.obs, fits)
            elif self.handheld:
                from accellog.navigate.handheld_evaluate import CANNOT_JUDGE

                md = "\n".join(views.table_markdown(tables.handheld_eval_table(h)) for h in self.handheld)
                rec.log_document("results/handheld", md + "\n\n" + CANNOT_JUDGE)
                fits = {h.label: _WindowResiduals(h.resid_g[:, None]) for h in self.handheld}
                log_panels(rec, panels(self.obs, fits))  # the norm residual against each driver
            else:
                views.log_evaluations(rec, self.single)


@dataclass
class _WindowResiduals:
    """The window residuals of one evaluation, as present.residual_views plots a fit's (g)."""

    residual_g: np.ndarray


def run_evaluate_report(
    test: str | os.PathLike,
    cal_paths: list,  # calibration files or Calibration objects
    *,
    until_s: float | None = None,
    max_samples: int | None = None,
    at_s: float = 60.0,
    stream: bool = True,
) -> EvaluationReport:
    """Residual of calibrated static data vs gravity and the displacement, per calibration file.

    An MCAP session streams chunk by chunk when `stream` (memory independent of its length; the
    .rrd of a run needs the samples: stream=False); other inputs are read whole."""
    cals = [as_calibration(c) for c in cal_paths]
    names = [c.model_spec.get("name", "") for c in cals]
    labels = (
        [Path(c.path or f"cal{i}").stem for i, c in enumerate(cals)] if len(set(names)) < len(names) else None
    )  # same-model files apart
    try:
        return _labelled_or_static(test, cals, labels, until_s=until_s, max_samples=max_samples, at_s=at_s,
                                   stream=stream)  # fmt: skip
    except InputError as exc:
        return _handheld_report(test, cals, labels, at_s, exc)


def _handheld_report(
    test, cals: list[Calibration], labels, at_s: float, refused: InputError
) -> EvaluationReport:
    """A session without pose labels that is not one static hold (it moves, its mean is not 1 g):
    judged on its detected static intervals with the gravity-norm residual
    (navigate.handheld_evaluate). `refused` (the single-hold error) is raised again when the session
    is labelled or fewer than 2 distinct static orientations are found."""
    from accellog.navigate.handheld_evaluate import detect_intervals, evaluate_handheld

    try:
        data = load_input(test)
        if not isinstance(data, Session) or data.poses:
            raise refused
        obs, intervals = detect_intervals(data)
    except InputError:
        raise refused from None
    g = cals[0].local_gravity_mps2 if cals else data.meta.local_gravity_mps2
    name = data.path or data.meta.source
    rep = EvaluationReport(data, cals, labels, at_s, obs=obs)
    rep.handheld = [
        evaluate_handheld(obs, intervals, c, session=name, raw_gravity_mps2=g) for c in [None, *cals]
    ]
    for h, lab in zip(rep.handheld[1:], labels or [], strict=False):
        h.label = lab
    return rep


def _labelled_or_static(
    test, cals: list[Calibration], labels, *, until_s, max_samples, at_s: float, stream: bool
) -> EvaluationReport:
    """A labelled multi-pose session hold by hold, or one static hold (an MCAP file chunk by chunk
    when stream; damaged chunks or a model reading dT/dt: in memory)."""
    if stream and can_stream(test):
        s = open_streamed(test, observe=False, check_times=False)  # one hold: checked in the evaluate pass
        if s is not None and len(s.poses) > 1:
            rep = _streamed_poses(test, cals, labels, until_s=until_s, max_samples=max_samples, at_s=at_s)
            if rep is not None:
                return rep
        elif s is not None:
            evs = evaluate_blocks(file_blocks(s.path, s.meta, s.poses), targets(cals, labels),
                                  until_s=until_s, max_samples=max_samples)  # fmt: skip
            if evs is not None:
                return EvaluationReport(s, cals, labels, at_s, single=evs)
    data = load_input(test)
    rep = EvaluationReport(data, cals, labels, at_s)
    if isinstance(data, Session) and len(data.poses) > 1:
        _refuse_cut(len(data.poses), until_s, max_samples, data.path)
        _pose_evaluations(rep, observations(data), data.meta, data.path or data.meta.source)
        return rep
    rep.single = run_evaluate(
        data if isinstance(data, Session) else test,
        cals,
        until_s=until_s,
        max_samples=max_samples,
        labels=labels,
    )
    return rep


def _pose_evaluations(rep: EvaluationReport, obs: ObsTable, meta, session: str) -> None:
    """The raw reading, then each calibration, window by window (gravity of the first calibration)."""
    g = rep.cals[0].local_gravity_mps2 if rep.cals else meta.local_gravity_mps2
    rep.obs = obs
    rep.poses = [
        evaluate_pose_obs(obs, c, at_s=rep.at_s, raw_gravity_mps2=g, session=session)
        for c in [None, *rep.cals]
    ]


def _refuse_cut(n_poses: int, until_s: float | None, max_samples: int | None, where: str | None) -> None:
    if until_s is not None or max_samples is not None:
        raise InputError(
            f"--until-s/--max-samples cut a single static hold; this session has {n_poses} labelled holds",
            where=where,
        )


def _streamed_poses(
    test, cals: list[Calibration], labels, *, until_s, max_samples, at_s: float
) -> EvaluationReport | None:
    """The holds of a labelled MCAP file evaluated from its streamed observations; None: damaged
    chunks (the whole-session path reads it)."""
    s = open_streamed(test, observe=False)  # the time-stamp check before the observation pass
    if s is None:
        return None
    rep = EvaluationReport(s, cals, labels, at_s)
    _refuse_cut(len(s.poses), until_s, max_samples, s.path)
    _pose_evaluations(rep, stream_observations(s.path, labels=(s.meta, s.poses, [])), s.meta, s.path)
    return rep


@dataclass
class Integration(JsonResult):
    """v(t) (m/s) and d(t) (m) of a static session after a calibration (or of the raw reading);
    velocity_mps None when the series were streamed to the CSV (run_integrate with output)."""

    session_path: str
    cal_path: str | None
    evaluation: Evaluation
    velocity_mps: np.ndarray | None
    written: Path | None = None

    def csv_text(self) -> str:
        """t_s, vx_mps, vy_mps, vz_mps, x_m, y_m, z_m (one row per sample)."""

        ev = self.evaluation
        rows = format_rows(np.column_stack([ev.t_s, self.velocity_mps, ev.disp_series_m]))
        return CSV_HEADER + rows.decode("ascii")

    def to_dict(self, output: str = "") -> dict:
        ev = self.evaluation
        return {
            "session": self.session_path,
            "calibration": self.cal_path,
            "label": ev.label,
            "t_end_s": ev.t_end_s,
            "disp_end_m": ev.disp_end_m.tolist(),
            "displacement_at_s": {f"{ts:g}": ev.disp_at(ts).tolist() for ts in ev.times_s},
            "output": output,
        }


CSV_HEADER = "t_s,vx_mps,vy_mps,vz_mps,x_m,y_m,z_m\n"


def run_integrate(
    path: str | os.PathLike,
    cal_path: Calibration | Path | None = None,
    *,
    until_s: float | None = None,
    output: Path | None = None,
    stream: bool = True,
) -> Integration:
    """Integrate a static session twice over its recorded (uneven) timestamps, gravity removed with
    local gravity: a = f g_local - up g_local (m/s^2); v, d by cumulative trapezoid. With output,
    the CSV (CSV_HEADER, one row per sample) is written atomically as the blocks are integrated (an
    MCAP file chunk by chunk when stream: memory independent of its length); without output the
    session is read in memory."""
    c = as_calibration(cal_path) if cal_path is not None else None
    cp = c.path if c is not None else None
    tgts = [Target(c)] if c is not None else targets([])
    load = lambda: _session_input(path, "integrate")  # noqa: E731
    vel: list[np.ndarray] = []

    def run(src: Blocks, rows=None) -> list[Evaluation] | None:
        vel.clear()

        def sink(_k: int, t: np.ndarray, v: np.ndarray, d: np.ndarray) -> None:
            if src.in_memory:
                vel.append(v)
            if rows is not None:
                rows(t, v, d)

        return evaluate_blocks(src, tgts, until_s=until_s, on_block=sink)

    if output is None:
        evs, _ = run_on_blocks(path, run, load, stream=False)
        return Integration(str(path), cp, evs[-1], np.concatenate(vel))
    with atomic_output(output, inputs=(path, cp)) as tmp, open(tmp, "wb") as f:

        def csv_pass(src: Blocks) -> list[Evaluation] | None:
            f.seek(0)
            f.truncate()  # a pass that met damaged chunks wrote rows: the whole session writes them again
            f.write(CSV_HEADER.encode("ascii"))
            return run(src, lambda t, v, d: f.write(format_rows(np.column_stack([t, v, d]))))

        evs, _ = run_on_blocks(path, csv_pass, load, stream=stream)
    return Integration(str(path), cp, evs[-1], np.concatenate(vel) if vel else None, Path(output))
