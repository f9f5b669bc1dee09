"""The static-session stages behind `segment`, `evaluate` and `integrate`, each returning a typed result.

- `run_segment(session)`           -> SegmentResult (per-pose statistics, windowed observations)
- `run_evaluate_report(test, cals)` -> EvaluationReport: one static hold (the seed's tables 4 and 5)
                                      or, for a session with several labelled holds, hold by hold
- `run_integrate(session, cal)`     -> Integration: v(t), d(t) of a static session (m/s, m)
"""

from __future__ import annotations

import io
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from accellog.calibrate.calibration import Calibration, load_calibration
from accellog.calibrate.obs_file import obs_to_dict
from accellog.calibrate.segment import PoseStats, observations, pose_stats
from accellog.core.errors import InputError
from accellog.core.jsonio import JsonResult
from accellog.core.session import ObsTable, Session
from accellog.core.timeseries import cumtrapz
from accellog.flows.stages import load_input, run_evaluate
from accellog.flows.stream_input import StreamedSession, can_stream, open_streamed
from accellog.navigate.evaluate import Evaluation, PoseEvaluation, evaluate_poses
from accellog.present import tables, views
from accellog.present.rrd.recording import RunRecording


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

    data: Session | ObsTable
    cals: list[Calibration]
    labels: list[str] | None
    at_s: float
    single: list[Evaluation] = field(default_factory=list)
    poses: list[PoseEvaluation] = field(default_factory=list)

    @property
    def kind(self) -> str:
        return "poses" if self.poses else "single"

    def to_dict(self) -> dict:
        if self.poses:
            return {
                "kind": "poses",
                "raw": self.poses[0].to_dict(),
                "calibrated": [p.to_dict() for p in self.poses[1:]],
            }
        return {"raw": self.single[0].to_dict(), "calibrated": [e.to_dict() for e in self.single[1:]]}

    def calibrations_by_label(self) -> dict[str, Calibration]:
        rows = self.poses[1:] if self.poses else self.single[1:]
        return dict(zip(self.labels or [r.label for r in rows], self.cals, strict=True))

    def write_rrd(self, path: str | Path) -> None:
        """The session (raw and calibrated) and the evaluation (tracks, or per-pose residual tables)."""

        with RunRecording(f"save:{path}") as rec:
            if isinstance(self.data, Session):
                views.log_session(rec, self.data, calibrations=self.calibrations_by_label())
            if self.poses:
                md = "\n".join(views.table_markdown(tables.pose_eval_table(p)) for p in self.poses)
                rec.log_document("results/poses", md)
            else:
                views.log_evaluations(rec, self.single)


def run_evaluate_report(
    test: str | os.PathLike,
    cal_paths: list[Path],
    *,
    until_s: float | None = None,
    max_samples: int | None = None,
    at_s: float = 60.0,
) -> EvaluationReport:
    """Residual of calibrated static data vs gravity and the displacement, per calibration file."""
    cals = [load_calibration(c) for c in cal_paths]
    names = [c.model_spec.get("name", "") for c in cals]
    labels = [p.stem for p in cal_paths] if len(set(names)) < len(names) else None  # same-model files apart
    data = load_input(test)
    rep = EvaluationReport(data, cals, labels, at_s)
    if isinstance(data, Session) and len(data.poses) > 1:
        if until_s is not None or max_samples is not None:
            raise InputError(
                "--until-s/--max-samples cut a single static hold; this session has "
                f"{len(data.poses)} labelled holds",
                where=data.path,
            )
        g = cals[0].local_gravity_mps2 if cals else None
        rep.poses = [evaluate_poses(data, None, at_s=at_s, local_gravity_mps2=g)]
        rep.poses += [evaluate_poses(data, c, at_s=at_s) for c in cals]
        return rep
    rep.single = run_evaluate(
        data if isinstance(data, Session) else test,
        cals,
        until_s=until_s,
        max_samples=max_samples,
        labels=labels,
    )
    return rep


@dataclass
class Integration(JsonResult):
    """v(t) (m/s) and d(t) (m) of a static session after a calibration (or of the raw reading)."""

    session_path: str
    cal_path: str | None
    evaluation: Evaluation
    velocity_mps: np.ndarray

    def csv_text(self) -> str:
        """t_s, vx_mps, vy_mps, vz_mps, x_m, y_m, z_m (one row per sample)."""

        buf = io.StringIO()
        buf.write("t_s,vx_mps,vy_mps,vz_mps,x_m,y_m,z_m\n")
        ev = self.evaluation
        np.savetxt(
            buf, np.column_stack([ev.t_s, self.velocity_mps, ev.disp_series_m]), delimiter=",", fmt="%.9g"
        )
        return buf.getvalue()

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


def run_integrate(
    path: str | os.PathLike, cal_path: Path | None = None, *, until_s: float | None = None
) -> Integration:
    """Integrate a static session twice over its recorded (uneven) timestamps, gravity removed with
    local gravity: a = f g_local - up g_local (m/s^2); v, d by cumulative trapezoid."""
    data = _session_input(path, "integrate")
    c = load_calibration(cal_path) if cal_path is not None else None
    ev = run_evaluate(data, [c] if c else [], include_raw=c is None, until_s=until_s)[-1]
    v = cumtrapz(ev.t_s, ev.resid_series_mps2)  # the residual acceleration (m/s^2) is what integrates to d
    return Integration(str(path), str(cal_path) if cal_path else None, ev, v)
