"""The batch stages as plain functions, each returning a typed result (the CLI presents it).

Every stage opens its session input once (``store.source.open_source``: a path, a Session or a
Source; a finished MCAP file streams chunk by chunk, anything else is one block in memory) and makes
its passes over it; observation tables (observations JSON, capstone pose tables) are read by
``calibrate.observe.obs_file.read_obs_table``.

- `load_input(path)`        -> Session, or ObsTable for an observation table
- `run_fit(...)`            -> FitOutcome (ObsTable, FitResult, Calibration)
- `run_segment(...)`        -> SegmentResult (per-pose statistics, windowed observations)
- `run_evaluate(...)`       -> list[Evaluation] (raw reading first when include_raw)
- `run_evaluate_report(...)`-> EvaluationReport: one static hold (the seed's tables 4 and 5), hold
                               by hold for several labelled holds, or per detected interval (hand-held)
- `run_drift(...)`          -> DriftOutcome (calibration + drift model, before/after on the fit session)
- `run_integrate(...)`      -> Integration: v(t), d(t) of a static session (m/s, m)
- `run_apply(...)` (accellog.flows.apply) -> Path of an MCAP copy with /derived/accel_calibrated (g)
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from accellog.calibrate.calfile.calibration import (
    Calibration,
    as_calibration,
    convention_truth_g,
    load_calibration,
    source_provenance,
)
from accellog.calibrate.calfile.sections import check_one_device
from accellog.calibrate.gyro.calibrate import (
    calibrate_source,
    calibrate_sources,
    first_pass_of,
    temp_order_of,
    warn_clipped_moves,
)
from accellog.calibrate.model.compose import build_model, orientation_free_model
from accellog.calibrate.model.variance import fit_with_uncertainty
from accellog.calibrate.observe.detect import TooFewOrientations
from accellog.calibrate.observe.detected_holds import (
    field_observations,
    fit_observations,
    fit_stops,
    judge_stops,
)
from accellog.calibrate.observe.obs_file import obs_to_dict, read_obs_table
from accellog.calibrate.observe.segment import (
    PoseStats,
    check_coverage,
    near_one_direction,
    observations,
    observe_riding,
)
from accellog.core.errors import InputError, ModelError
from accellog.core.forked import started
from accellog.core.heap import trim_heap
from accellog.core.jsonio import JsonResult
from accellog.core.notices import note
from accellog.core.numeric import load_solver, solver_loaded
from accellog.core.numfmt import format_rows
from accellog.core.session import ObsTable, Session
from accellog.core.units import STANDARD_GRAVITY_MPS2
from accellog.store.atomic import atomic_output
from accellog.store.source import Source, open_source, read_whole

if TYPE_CHECKING:  # the evaluate stages import these when called (`fit` does without them)
    from accellog.calibrate.calfile.drift_model import DriftModel
    from accellog.navigate.evaluate import Evaluation, HandheldEvaluation, PoseEvaluation

SessionInput = Session | Source | str | os.PathLike


# ------------------------------------------------------------------------------------------ inputs


def load_input(
    path: str | os.PathLike, *, n_per_pose: int | None = None, check_times: bool = True
) -> Session | ObsTable:
    """Any supported input file whole: an ObsTable for an observation table (obs_file.read_obs_table),
    else the Session (store.source.read_whole; check_times False: degenerate time stamps are not
    refused, for tools that report them, e.g. doctor)."""
    table = read_obs_table(path, n_per_pose=n_per_pose)
    return table if table is not None else read_whole(path, check_times=check_times)


def _cal(x: Calibration | str | os.PathLike) -> Calibration:
    return x if isinstance(x, Calibration) else load_calibration(x)


# ------------------------------------------------------------------------------------------ fit


def _with_recovered(d: dict, cal: Calibration) -> dict:
    """d plus 'recovered': what was salvaged from truncated inputs (the calibration's provenance)."""
    rec = [x.recovered for x in cal.sources if x.recovered]
    return {**d, "recovered": rec} if rec else d


@dataclass
class FitOutcome(JsonResult):
    """A fitted model: the observations, the FitResult and the Calibration built from it."""

    obs: ObsTable
    fit: Any  # accellog.calibrate.model.fit.FitResult
    cal: Calibration

    def to_dict(self) -> dict:
        d = self.fit.to_dict()
        d["terms"] = list(self.fit.model.terms)
        d["gravity_convention"] = self.cal.gravity_convention
        d["local_gravity_mps2"] = self.cal.local_gravity_mps2
        d["n_poses"] = len(self.obs.pose_names)
        return _with_recovered(d, self.cal)

    def write_rrd(self, path: str | os.PathLike, data: Session | ObsTable | None = None) -> None:
        """Recording of the fit (residuals per pose) and, for a session, its samples raw and calibrated."""
        from accellog.present import views
        from accellog.present.rrd.offload import open_recording

        with open_recording(f"save:{path}") as rec:
            if isinstance(data, Session):
                views.log_session(rec, data, calibrations={self.fit.model.name: self.cal})
            views.log_fit(rec, self)


def run_fit(
    data: SessionInput | ObsTable | Sequence[SessionInput],
    model: str = "model3",
    *,
    add: Sequence[str] = (),
    effects_file: str | os.PathLike | None = None,
    weighted: bool = True,
    orientation_free: bool = False,
    gravity: str = "local",
    local_gravity_mps2: float | None = None,
    window_s: float = 2.0,
    trim_s: float = 0.5,
    n_per_pose: int | None = None,
    obs: ObsTable | None = None,
    gyro: bool = True,
    uncertainty: str = "noise",
    relabel: bool = False,
    prior: Calibration | str | os.PathLike | None = None,
    aging: Mapping[str, float] | None = None,
) -> FitOutcome:
    """Segment (if needed) and fit one model; returns the calibration with its uncertainties.

    data: a session (path, Session or Source: a labelled MCAP file streams, its observations and the
    gyro calibration's first pass in one pass), an ObsTable or an observation-table file; obs: the
    observations of the session, when made already. gravity: 'seed' (truth 1 per pose) or 'local'
    (g_local/g0 standard g). local_gravity_mps2: default the session's (meta.local_gravity_mps2), g0
    for pose tables. orientation_free: fit |correct(reading)| = truth_g without pose labels;
    unlabelled sessions are segmented by detect_static (threshold sweep scored by the fit), their
    stops, in too few directions for the model, fitted in what they identify (_field_fit). gyro: also
    calibrate the gyro from the holds and the moves between them (cal.gyro). uncertainty: 'noise',
    'between_hold' or 'jackknife' (accellog.calibrate.model.variance). relabel: replace hold labels
    that contradict the measured gravity direction (each change is a note on stderr).

    prior: a calibration of the device (the lab's) that the stops of the unlabelled session(s) update
    (calibrate.model.prior; aging: how far each effect may have moved since, default prior.AGING);
    data may then be several sessions of one device (a list), their stops pooled (_field_fit).
    """
    field = dict(model=model, add=add, effects_file=effects_file, aging=aging, gravity=gravity, weighted=weighted,
                 local_gravity_mps2=local_gravity_mps2, window_s=window_s, trim_s=trim_s, gyro=gyro,
                 uncertainty=uncertainty)  # fmt: skip
    if prior is not None or isinstance(data, (list, tuple)):
        many = list(data) if isinstance(data, (list, tuple)) else [data]
        return _field_fit(many, None if prior is None else _prior(prior, add, effects_file), **field)
    table, src, name = _fit_input(data, obs, n_per_pose)
    m = build_model(model, add=list(add), effects_file=effects_file)
    if not orientation_free and src is not None and table is None and not src.poses:  # decided here
        orientation_free, m = True, orientation_free_model(m, name)
    if local_gravity_mps2 is None:
        local_gravity_mps2 = STANDARD_GRAVITY_MPS2 if src is None else src.meta.local_gravity_mps2
    lg = float(local_gravity_mps2)
    truth = convention_truth_g(gravity, lg)
    detected, first = None, None  # static intervals found in an unlabelled session; the gyro's first pass
    if src is not None and table is None and (relabel or orientation_free):  # relabelled or detected
        try:
            table, detected, src = fit_observations(src, m, gravity_g=truth, relabel=relabel, window_s=window_s,
                                                    trim_s=trim_s)  # fmt: skip
        except TooFewOrientations as exc:  # stops near level, six faces: fit what they identify
            return _few_directions(src, exc, field)
    elif src is not None and table is None:
        table, first, src = _labelled_pass(src, window_s=window_s, trim_s=trim_s, gyro=gyro)
    assert table is not None  # given, read from its file, or observed in the session above
    if not orientation_free:
        try:
            check_coverage(table, needs_scale=m.n_params > 3 or any(t != "bias" for t in m.terms), where=name)
        except ModelError as exc:  # labelled holds near level (a robot's stops): what they identify
            return _few_directions(src if near_one_direction(table) else None, exc, field)  # else refused
    fit = fit_with_uncertainty(table, m, orientation_free=orientation_free, weighted=weighted, gravity_g=truth,
                               uncertainty=uncertainty)  # fmt: skip
    if detected is not None:  # stops found in an unlabelled session: how well they determine the fit
        judge_stops(fit, table)
    cal = Calibration.from_session_fit(fit, table, src, gravity_convention=gravity, local_gravity_mps2=lg,
                                       detected=detected)  # fmt: skip
    if gyro and src is not None:
        fit.release_jacobian()  # not held through the gyro passes (read again, it is remade)
        trim_heap()
        cal.gyro = calibrate_source(src, temp_order=temp_order_of(fit.model.terms), first=first)
    warn_clipped_moves(fit, cal)  # moves left out of the gyro fit: said, and in the file
    return FitOutcome(obs=table, fit=fit, cal=cal)


def _fit_input(
    data: SessionInput | ObsTable | Sequence[SessionInput], obs: ObsTable | None, n_per_pose: int | None
) -> tuple[ObsTable | None, Source | None, str]:
    """What run_fit was given: (the observation table, given or read from a table file, or None;
    the session's source, None for a table alone; the name said in messages)."""
    if isinstance(data, ObsTable):
        return data, None, data.session
    table = (
        read_obs_table(data, n_per_pose=n_per_pose)
        if obs is None and isinstance(data, (str, os.PathLike))
        else obs
    )
    if table is not None and obs is None:  # a table file: no session
        return table, None, table.session
    if not isinstance(data, (Session, Source, str, os.PathLike)):
        raise InputError(
            f"fit: cannot read a {type(data).__name__} (a path, Session, ObsTable or list of them)"
        )
    src = open_source(data, what="fit")
    return table, src, src.where


def _few_directions(src: Source | None, exc: TooFewOrientations | ModelError, field: dict) -> FitOutcome:
    """The fit of what a session's stops identify (_field_fit without a prior, its labelled holds
    or detected still intervals as the stops), said with why the full model could not be fitted;
    an observation table alone (no samples) and a truncated file (its labels went with its end) are
    refused instead."""
    if src is None or any(e.kind == "recovered" for e in src.events):
        raise exc
    note(f"{exc}. Fitting only what these stops identify instead (below)")
    return _field_fit([src], None, as_stops=True, **field)


def _labelled_pass(src: Source, *, window_s: float, trim_s: float, gyro: bool):
    """(observations, the gyro's first pass or None, Source) of a labelled session in one pass: in a
    forked child while this process imports the solver."""
    with started(observe_riding, src, window_s=window_s, trim_s=trim_s, rider=first_pass_of if gyro else None,
                 what=f"reading {src.where}", meanwhile=not solver_loaded()) as reading:  # fmt: skip
        if reading.forked:
            load_solver()  # meanwhile; in-process the first fit imports it
        return reading.result()


def _prior(prior: Calibration | str | os.PathLike, add: Sequence[str], effects_file) -> Calibration:
    """The lab calibration a field fit updates, with the effects of `add` it lacks added at their
    typical size (Calibration.with_effects; a note says so): the stops update them too."""
    lab = prior if isinstance(prior, Calibration) else load_calibration(prior, effects_file)
    cal = lab.with_effects(list(add)) if add else lab
    new = [n for n in cal.param_names if n not in lab.param_names]
    if new:
        note(f"{lab.path or 'the prior'}: {', '.join(new)} not in the prior: added at their initial values "
             "with 1-sigma = the effect's typical size")  # fmt: skip
    return cal


def _field_fit(inputs, prior: Calibration | None, *, model, add, effects_file, aging, gravity, weighted,
               local_gravity_mps2, window_s, trim_s, gyro, uncertainty, as_stops=False) -> FitOutcome:  # fmt: skip
    """run_fit of several sessions of one device, or of field sessions with a prior. Labelled
    sessions without a prior (a freezer warm-up and a room cool-down, several days): their windows
    pooled (loso.concat_obs, each session's holds its own poses) in one labelled fit with one
    temperature model. Otherwise (a robot's run, a drone between flights) the still intervals of
    each are detected (moves ignored), their observations pooled and fitted orientation-free with
    the prior (or, without one, only what the stops identify; as_stops: labelled holds too, their
    poses too few to fit the model). The gyro bias curve from the holds (stops) of all of them."""
    from accellog.calibrate.diagnosis.loso import concat_obs
    from accellog.calibrate.model.prior import Prior, untempered_warning

    srcs = [open_source(x, what="fit") for x in inputs]
    check_one_device(srcs, prior)
    joint = prior is None and not as_stops and all(src.poses for src in srcs)  # what they hold, decided here
    pri = None
    if prior is not None:
        m, gravity = prior.model, prior.gravity_convention
        pri = Prior.of(prior.param_names, prior.theta, prior.cov, m, aging=aging, what=prior.path or "prior")
    else:
        m = build_model(model, add=list(add), effects_file=effects_file)
        if not joint:
            m = orientation_free_model(m, srcs[0].where)
    lg = float(srcs[0].meta.local_gravity_mps2 if local_gravity_mps2 is None else local_gravity_mps2)
    truth = convention_truth_g(gravity, lg)
    if joint:
        found: list = [(src, None) for src in srcs]
        obs = concat_obs([observations(src, window_s=window_s, trim_s=trim_s) for src in srcs])
        needs_scale = m.n_params > 3 or any(t != "bias" for t in m.terms)
        check_coverage(obs, needs_scale=needs_scale, where=" + ".join(s.where for s in srcs))
        fit = fit_with_uncertainty(obs, m, orientation_free=False, weighted=weighted, gravity_g=truth,
                                   uncertainty=uncertainty)  # fmt: skip
    else:
        parts, found = field_observations(srcs, m, truth, pri, window_s=window_s, trim_s=trim_s)
        obs = concat_obs(parts) if len(parts) > 1 else parts[0]
        fit = fit_stops(obs, m, truth, pri, weighted=weighted, uncertainty=uncertainty, note_what=True)
        w = None if prior is None else untempered_warning(fit.model, obs.temp_degC, prior.path or "the prior")
        if w is not None:
            note(w)
            fit.warnings.append(w)
    cal = Calibration.from_session_fit(fit, obs, found[0][0], gravity_convention=gravity, local_gravity_mps2=lg,
                                       detected=found[0][1] if len(found) == 1 else None)  # fmt: skip
    cal.sources = [source_provenance(src, None) for src, _ in found]
    if gyro:
        fit.release_jacobian()  # not held through the gyro passes
        trim_heap()
        cal.gyro = calibrate_sources([src for src, _ in found], temp_order=temp_order_of(fit.model.terms),
                                     still_ref=None if prior is None else prior.gyro)  # fmt: skip
    return FitOutcome(obs=obs, fit=fit, cal=cal)


# ------------------------------------------------------------------------------------------ segment


@dataclass
class SegmentResult(JsonResult):
    """Per-pose statistics and the windowed observation table of one session."""

    session: Source
    stats: list[PoseStats]
    obs: ObsTable
    window_s: float

    def obs_dict(self) -> dict:
        return obs_to_dict(self.obs)

    def to_dict(self, output: str = "") -> dict:
        return {"poses": [p.to_dict() for p in self.stats], "n_observations": self.obs.n, "output": output}


def run_segment(data: SessionInput, *, window_s: float = 2.0, trim_s: float = 0.5) -> SegmentResult:
    """Statistics of every labelled hold and observations of ~window_s (s), trim_s (s) dropped at
    both ends, in one pass."""
    src = open_source(data, what="segment")
    stats: list[PoseStats] = []
    table = observations(src, window_s=window_s, trim_s=trim_s, stats_out=stats)
    return SegmentResult(src, stats, table, window_s)


# ------------------------------------------------------------------------------------------ evaluate


def run_evaluate(
    test: SessionInput,
    cal: Calibration | str | os.PathLike | Sequence[Calibration],
    *,
    include_raw: bool = True,
    times_s: Sequence[float] = (10.0, 30.0, 60.0),
    until_s: float | None = None,
    max_samples: int | None = None,
    labels: Sequence[str] | None = None,
    stream: bool = False,
) -> list[Evaluation]:
    """Evaluate calibration(s) on a static test session; the raw reading first when include_raw.
    stream: an MCAP file chunk by chunk (its evaluations then keep no series to plot), else in memory."""
    from accellog.navigate.evaluate import evaluate_blocks, targets

    cals = [_cal(cal)] if isinstance(cal, (Calibration, str, os.PathLike)) else [_cal(c) for c in cal]
    src = open_source(test, what="evaluate")
    if not stream:
        src.whole()  # the series are kept for plots
    return evaluate_blocks(src, targets(cals, labels, include_raw), times_s=times_s, until_s=until_s,
                           max_samples=max_samples)  # fmt: skip


@dataclass
class EvaluationReport(JsonResult):
    """`evaluate` of one or more calibrations: ``single`` (one static hold: raw first, then each
    calibration) or ``poses`` (a session with several labelled holds, evaluated hold by hold)."""

    data: Source
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
            from accellog.navigate.window_evaluation import CANNOT_JUDGE

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

        from accellog.present import tables, views
        from accellog.present.residual_views import log_panels, log_residuals_vs_drivers, panels
        from accellog.present.rrd.offload import open_recording

        with open_recording(f"save:{path}") as rec:
            if self.data.session is not None:  # in memory
                views.log_session(rec, self.data.session, calibrations=self.calibrations_by_label())
            obs = self.obs  # the windows judged: set for pose and hand-held evaluations
            assert obs is not None or not (self.poses or self.handheld)
            if self.poses and obs is not None:
                md = "\n".join(views.table_markdown(tables.pose_eval_table(p)) for p in self.poses)
                passes = [t for t in (tables.pass_eval_table(p) for p in self.poses) if t is not None]
                md += "".join("\n" + views.table_markdown(t) for t in passes)
                md += "".join(f"\n- {f}" for p in self.poses for f in p.flags)
                rec.log_document("results/poses", md)
                fits = {p.label: _WindowResiduals(p.window_resid_g) for p in self.poses}
                log_residuals_vs_drivers(rec, obs, fits)
            elif self.handheld and obs is not None:
                from accellog.navigate.window_evaluation import CANNOT_JUDGE

                md = "\n".join(views.table_markdown(tables.handheld_eval_table(h)) for h in self.handheld)
                rec.log_document("results/handheld", md + "\n\n" + CANNOT_JUDGE)
                fits = {h.label: _WindowResiduals(h.resid_g[:, None]) for h in self.handheld}
                log_panels(rec, panels(obs, fits))  # the norm residual against each driver
            else:
                views.log_evaluations(rec, self.single)


@dataclass
class _WindowResiduals:
    """The window residuals of one evaluation, as present.residual_views plots a fit's (g)."""

    residual_g: np.ndarray


def run_evaluate_report(
    test: SessionInput,
    cal_paths: list,  # calibration files or Calibration objects
    *,
    until_s: float | None = None,
    max_samples: int | None = None,
    at_s: float = 60.0,
    stream: bool = True,
) -> EvaluationReport:
    """Residual of calibrated static data vs gravity and the displacement, per calibration file
    (navigate.evaluate.evaluate_source: one static hold, hold by hold, or hand-held, from what the
    session holds). An MCAP session streams chunk by chunk when `stream` (memory independent of its length; the
    .rrd of a run needs the samples: stream=False); other inputs are read whole."""
    cals = [as_calibration(c) for c in cal_paths]
    names = [c.model_spec.get("name", "") for c in cals]
    labels = (
        [Path(c.path or f"cal{i}").stem for i, c in enumerate(cals)] if len(set(names)) < len(names) else None
    )  # same-model files apart
    from accellog.navigate.evaluate import evaluate_source

    src = open_source(test, what="evaluate")
    if not stream:
        src.whole()  # the .rrd draws the samples
    ev = evaluate_source(src, cals, labels, until_s=until_s, max_samples=max_samples, at_s=at_s)
    return EvaluationReport(
        src, cals, labels, at_s, single=ev.single, poses=ev.poses, obs=ev.obs, handheld=ev.handheld
    )


@dataclass
class DriftOutcome(JsonResult):
    """Drift model fitted on one static session (cal = input calibration + drift)."""

    cal: Calibration
    drift: DriftModel
    fit_eval: Evaluation  # the fit session after the calibration and the drift model

    def to_dict(self) -> dict:
        d = {
            "drift": self.drift.to_dict(),
            "fit_session": self.fit_eval.session,
            "disp_end_m": self.fit_eval.disp_end_m.tolist(),
            "disp_end_after_drift_m": None
            if self.fit_eval.disp_end_drift_m is None
            else self.fit_eval.disp_end_drift_m.tolist(),
            "t_end_s": self.fit_eval.t_end_s,
        }
        return _with_recovered(d, self.cal)

    def write_rrd(self, path: str | os.PathLike, data: Session | ObsTable | None = None) -> None:
        """Recording of the static session calibrated, with and without the drift model."""
        from accellog.present import views
        from accellog.present.rrd.offload import open_recording

        with open_recording(f"save:{path}") as rec:
            if isinstance(data, Session):
                views.log_session(rec, data, calibrations={"calibrated + drift model": self.cal})
            views.log_evaluations(rec, [self.fit_eval])


def run_drift(
    static: SessionInput,
    cal: Calibration | str | os.PathLike,
    *,
    until_s: float | None = None,
    max_samples: int | None = None,
    stream: bool = True,
) -> DriftOutcome:
    """Fit the displacement-drift model on a calibrated static session (an MCAP file chunk by chunk
    when stream, else in memory: its evaluation keeps the series to plot)."""
    from accellog.navigate.drift import drift_blocks

    src = open_source(static, what="drift")
    if not stream:
        src.whole()
    cal_d, dm, ev = drift_blocks(src, _cal(cal), until_s=until_s, max_samples=max_samples)
    entry = source_provenance(src, None)
    if entry.recovered is not None:  # provenance: the drift was fitted on a recovered (truncated) file
        cal_d.sources = [*cal_d.sources, dataclasses.replace(entry, kind="drift")]
    return DriftOutcome(cal=cal_d, drift=dm, fit_eval=ev)


# ------------------------------------------------------------------------------------------ integrate


@dataclass
class Integration(JsonResult):
    """v(t) (m/s) and d(t) (m) of a static session after a calibration (or of the raw reading);
    velocity_mps None when the series were streamed to the CSV (run_integrate with output)."""

    session_path: str
    cal_path: str | None
    evaluation: Evaluation
    velocity_mps: np.ndarray | None
    written: Path | None = None

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
    data: SessionInput,
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
    from accellog.navigate.evaluate import Target, evaluate_blocks, targets

    c = as_calibration(cal_path) if cal_path is not None else None
    cp = c.path if c is not None else None
    tgts = [Target(c)] if c is not None else targets([])
    src = open_source(data, what="integrate")
    if output is None or not stream:
        src.whole()  # the velocity series is returned
    vel: list[np.ndarray] = []

    def one_pass(rows=None) -> list[Evaluation]:
        vel.clear()  # a pass run again (a damaged file read whole) starts afresh

        def sink(_k: int, t: np.ndarray, v: np.ndarray, d: np.ndarray) -> None:
            if src.in_memory:
                vel.append(v)
            if rows is not None:
                rows(t, v, d)

        return evaluate_blocks(src, tgts, until_s=until_s, on_block=sink)

    if output is None:
        return Integration(src.where, cp, one_pass()[-1], np.concatenate(vel))
    path = src.path if src.path is not None else src.whole().path  # in memory: no read
    with atomic_output(output, inputs=(path, cp)) as tmp, open(tmp, "wb") as f:

        def csv_pass(_src: Source) -> list[Evaluation]:
            f.seek(0)
            f.truncate()  # a pass that met damaged chunks wrote rows: the whole session writes them again
            f.write(CSV_HEADER.encode("ascii"))
            return one_pass(lambda t, v, d: f.write(format_rows(np.column_stack([t, v, d]))))

        evs = src.run(csv_pass)
    return Integration(src.where, cp, evs[-1], np.concatenate(vel) if vel else None, Path(output))
