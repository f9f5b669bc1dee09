"""Batch stages as plain functions (each returns a result object; the CLI presents it).

- `load_input(path)`        .mcap / capstone or imucal CSV / generic CSV -> Session; pose tables
                            (capstone six_position_data) and observation JSON -> ObsTable
                            (accellog.flows.inputs)
- `run_fit(...)`            -> FitOutcome (ObsTable, FitResult, Calibration); its input (a path, a
                            Session or an ObsTable) resolved once by `fit_input` into a FitInput
- `run_evaluate(...)`       -> list[Evaluation] (raw reading first when include_raw)
- `run_drift(...)`          -> DriftOutcome (calibration + drift model, before/after on the fit session)
- `run_apply(...)` (accellog.flows.apply) -> Path of an MCAP copy with /derived/accel_calibrated (g)
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from accellog.calibrate.calfile.calibration import Calibration, load_calibration, source_entry
from accellog.calibrate.calfile.sections import DetectedInterval, DeviceInfo, SensorInfo, SourceFile
from accellog.calibrate.gyro.calibrate import (
    calibrate_gyro,
    gyro_full_scale_dps,
    warn_clipped_moves,
)
from accellog.calibrate.gyro.model import GyroCalibration
from accellog.calibrate.model.compose import build_model
from accellog.calibrate.model.fit import fit_model, fit_orientation_free
from accellog.calibrate.observe.detect import detect_static, with_labels
from accellog.calibrate.observe.label_check import relabel_holds
from accellog.calibrate.observe.segment import check_coverage, observations
from accellog.core.errors import AccellogError, InputError, ModelError
from accellog.core.forked import started
from accellog.core.heap import trim_heap
from accellog.core.jsonio import JsonResult
from accellog.core.notices import note
from accellog.core.numeric import load_solver, solver_loaded
from accellog.core.session import ObsTable, Session
from accellog.core.units import STANDARD_GRAVITY_MPS2
from accellog.flows.inputs import load_input
from accellog.flows.stream_input import StreamedSession, can_stream, open_streamed
from accellog.store.stream import read_labels

if TYPE_CHECKING:  # run_evaluate/run_drift import these when called (`fit` does without them)
    from accellog.calibrate.calfile.drift_model import DriftModel
    from accellog.flows.static_input import StaticInput
    from accellog.navigate.evaluate import Evaluation

GRAVITY_CONVENTIONS = ("seed", "local")
"""'seed': truth = +-1 per pose (unit = one local g; the capstone study); 'local': truth =
g_local / g0 in standard g (the physical convention)."""


# ------------------------------------------------------------------------------------------ inputs
# (reading them: accellog.flows.inputs.load_input, imported here for run_fit and the stages' callers)


def _path_of(x: Session | ObsTable) -> str | None:
    """The file a loaded input came from (a pose table keeps its path in ObsTable.session)."""
    p = x.path if isinstance(x, Session) else x.session
    return p if p and Path(p).is_file() else None


def _source(data: Session | ObsTable, src: str | None, kind: str) -> SourceFile:
    """Provenance entry of the input; a recovered (truncated) session says what was kept."""
    from accellog.store.recovery import recovery_info

    entry = source_entry(src or _path_of(data), kind)
    info = recovery_info(data) if isinstance(data, Session) else None
    if info is not None:
        entry = dataclasses.replace(entry, recovered=info.to_dict())
    return entry


def _truth_g(gravity: str, local_gravity_mps2: float) -> float:
    if gravity not in GRAVITY_CONVENTIONS:
        raise InputError(f"unknown gravity convention {gravity!r}: use 'seed' or 'local'")
    return 1.0 if gravity == "seed" else local_gravity_mps2 / STANDARD_GRAVITY_MPS2


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


def make_obs(
    data: Session | ObsTable, *, window_s: float = 2.0, trim_s: float = 0.5, min_samples: int = 20
) -> ObsTable:
    """ObsTable of a Session (segment.observations) or the table itself."""
    if isinstance(data, ObsTable):
        return data
    return observations(data, window_s=window_s, trim_s=trim_s, min_samples=min_samples)


@dataclass
class FitInput:
    """run_fit's input resolved once (fit_input), whatever the caller gave: a path, a Session or an
    ObsTable. Exactly one of obs (observations made or given) and session (samples in memory,
    segmented by run_fit) is set, unless the caller gives obs for a session."""

    name: str  # the input in messages
    poses: list  # pose labels ([] for a pose table or observations)
    local_gravity_mps2: float  # the session's (m/s^2); g0 without a session
    sensor: SensorInfo
    device: DeviceInfo | None  # None: no session, the calibration keeps its default
    source: Callable[[], SourceFile]
    """source(): the provenance entry, hashed only when a calibration is built (a file that fails
    to fit is not read twice: a 2 GB truncated file costs its readable head, not a hash of 2 GB)."""
    obs: ObsTable | None
    session: Session | None
    gyro: Callable[[Any, list | None], GyroCalibration | None]
    """gyro(fit, detected intervals or None): the gyro calibration from the session's holds and moves."""


def fit_input(
    data: Session | ObsTable | str | os.PathLike,
    obs: ObsTable | None = None,
    *,
    whole: bool = False,
    relabel: bool = False,
    window_s: float = 2.0,
    trim_s: float = 0.5,
    n_per_pose: int | None = None,
    gyro: bool = False,
) -> FitInput:
    """FitInput of data: a labelled accellog MCAP file is streamed (bounded memory: its observations
    and, with gyro, the gyro calibration's first pass in one pass over the samples) unless the whole
    session is needed (whole: relabelling, orientation-free) or obs are given; other files are read
    (load_input); hold labels that contradict gravity are replaced when relabel (a note each)."""
    src = str(data) if isinstance(data, (str, os.PathLike)) else None
    if src is not None:
        if obs is None and not whole and can_stream(src) and read_labels(src)[1]:
            with started(open_streamed, src, window_s=window_s, trim_s=trim_s, gyro=gyro,
                         what=f"reading {src}", meanwhile=not solver_loaded()) as reading:  # fmt: skip
                if reading.forked:
                    load_solver()  # meanwhile (core.forked); in-process the first fit imports it
                streamed = reading.result()
            if streamed is not None:  # None: damaged chunks, read whole (load_input says what it skipped)
                return _streamed_input(streamed)
        data = load_input(src, n_per_pose=n_per_pose)
    if isinstance(data, ObsTable):
        return FitInput(data.session, [], STANDARD_GRAVITY_MPS2, SensorInfo.empty(), None, lambda: _source(data, src, ""),
                        data if obs is None else obs, None, lambda fit, detected: None)  # fmt: skip
    if relabel:
        data, changes = relabel_holds(data, trim_s=trim_s)
        for c in changes:
            note(f"{data.path or 'session'}: relabelled {c.pose!r} as {c.likely!r}: {c.line()}")
    session = data

    def whole_gyro(fit, detected) -> GyroCalibration | None:
        # unlabelled (hand-held) sessions: the gyro is calibrated on the detected static intervals
        # and the rotations between them (imu_tk style), not skipped
        return _gyro_calibration(with_labels(session, detected) if detected else session)

    m = session.meta
    return FitInput(session.path or m.source, session.poses, m.local_gravity_mps2, SensorInfo.from_meta(m),
                    DeviceInfo.from_key(m.device), lambda: _source(session, src, m.source), obs, session, whole_gyro)  # fmt: skip


def _streamed_input(s: StreamedSession) -> FitInput:
    """FitInput of a file streamed by open_streamed (its observations made in that pass)."""

    def streamed_gyro(fit, detected) -> GyroCalibration | None:
        fit.release_jacobian()  # not held through the gyro passes (read again, it is remade)
        trim_heap()
        return s.gyro_calibration()  # the moves, streamed from the file again (holds: in the obs pass)

    m = s.meta
    return FitInput(s.path, s.poses, m.local_gravity_mps2, SensorInfo.from_meta(m), DeviceInfo.from_key(m.device),
                    lambda: _source(s, s.path, m.source), s.obs, None, streamed_gyro)  # fmt: skip


def run_fit(
    data: Session | ObsTable | str | os.PathLike,
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
) -> FitOutcome:
    """Segment (if needed) and fit one model; returns the calibration with its uncertainties.

    gravity: 'seed' (truth 1 per pose) or 'local' (g_local/g0 standard g). local_gravity_mps2:
    default the session's (meta.local_gravity_mps2), g0 for pose tables. orientation_free: fit
    |correct(reading)| = truth_g without pose labels; unlabelled sessions are segmented by
    detect_static (threshold sweep scored by the orientation-free residual). gyro: also
    calibrate the gyro from the session's holds and the moves between them (stored in cal.gyro).
    uncertainty: 'noise' (window noise; scaled by the hold means' Birge ratio when they reject it),
    'between_hold' (plus the between-hold variance component) or 'jackknife' (leave one hold out);
    accellog.calibrate.model.variance (fit.uncertainty_note says which). relabel: replace
    hold labels that contradict the measured gravity direction (each change is a note on stderr).
    """
    fi = fit_input(data, obs, whole=relabel or orientation_free, relabel=relabel, window_s=window_s,
                   trim_s=trim_s, n_per_pose=n_per_pose, gyro=gyro)  # fmt: skip
    m = build_model(model, add=list(add), effects_file=effects_file)
    if not orientation_free and fi.obs is None and not fi.poses:
        orientation_free, m = True, _orientation_free_model(m, effects_file, fi.name)
    if local_gravity_mps2 is None:
        local_gravity_mps2 = fi.local_gravity_mps2
    truth = _truth_g(gravity, float(local_gravity_mps2))
    detected = None  # static intervals found in an unlabelled session
    obs = fi.obs
    if obs is None:
        obs, detected = _fit_observations(fi.session, m, truth, orientation_free, window_s, trim_s)
    fit = _fit_obs(obs, m, fi.name, orientation_free, weighted, truth, uncertainty)
    cal = _calibration(fit, obs, fi, gravity, float(local_gravity_mps2), detected)
    if gyro:
        cal.gyro = fi.gyro(fit, detected)
    warn_clipped_moves(fit, cal)  # moves left out of the gyro fit: said, and in the file
    return FitOutcome(obs=obs, fit=fit, cal=cal)


def _orientation_free_model(m, effects_file, where: str):
    """An unlabelled (hand-held) session is fitted orientation-free, said in a note; cross_axis (3 of its
    6 terms are a frame rotation, unobservable without labels) becomes misalignment_tri."""
    terms = ["misalignment_tri" if t == "cross_axis" else t for t in m.terms]
    swap = " with misalignment_tri for cross_axis" if terms != list(m.terms) else ""
    note(f"{where}: no pose labels: fitted orientation-free (|f| = g on the detected still intervals){swap}")
    return build_model("+".join(dict.fromkeys(terms)), effects_file=effects_file) if swap else m


def _fit_observations(
    session: Session, m, truth: float, orientation_free: bool, window_s: float, trim_s: float
):
    """(obs, detected static intervals or None): windowed observations of the holds, or of the static
    intervals detect_static finds in an unlabelled session for an orientation-free fit."""
    if not (orientation_free and not session.poses):
        return observations(session, window_s=window_s, trim_s=trim_s), None

    def cost(labels) -> float:
        o = observations(with_labels(session, labels), window_s=window_s, trim_s=0.0, check_units=False)
        return fit_orientation_free(o, m, weighted=False, gravity_g=truth).rms_g

    detected = detect_static(session, cost=cost)
    return observations(with_labels(session, detected), window_s=window_s, trim_s=0.0), detected


def _fit_obs(obs, m, name: str, orientation_free: bool, weighted: bool, truth: float, uncertainty: str):
    """The fit (orientation-free, or labelled after the pose coverage check), with the uncertainty asked."""
    if orientation_free:
        fit = fit_orientation_free(obs, m, weighted=weighted, gravity_g=truth)
    else:
        check_coverage(obs, needs_scale=m.n_params > 3 or any(t != "bias" for t in m.terms), where=name)
        fit = fit_model(obs, m, weighted=weighted, gravity_g=truth)
    from accellog.calibrate.model.variance import with_uncertainty

    return with_uncertainty(fit, obs, uncertainty)  # 'noise' too: scaled when the holds reject it


def _calibration(fit, obs, fi: FitInput, gravity: str, local_gravity_mps2: float, detected) -> Calibration:
    """The calibration of a fit: sensor, source, device and the detected intervals it used."""
    cal = Calibration.from_fit(
        fit,
        obs=obs,
        gravity_convention=gravity,
        local_gravity_mps2=local_gravity_mps2,
        sources=[fi.source()],
        sensor=fi.sensor,
    )
    if fi.device is not None:
        cal.device = fi.device
    if detected:  # hand-held: the static intervals the fit used go into the calibration file
        t = fi.session.t_s
        intervals = tuple(
            DetectedInterval(
                start_s=p.start_s,
                end_s=p.end_s,
                n=int(np.sum((t >= p.start_s) & (t < p.end_s))),
                up_sensor=tuple(float(x) for x in p.up_sensor),
            )
            for p in detected
        )
        cal.fit = dataclasses.replace(cal.fit, detected_intervals=intervals)
    return cal


def _gyro_calibration(session: Session) -> GyroCalibration | None:
    """Gyro bias (and scale/misalignment where the holds' orientations are known) from the same
    session, stored next to the accelerometer's; None when the session has no gyro or holds."""

    if session.gyro_dps is None or len(session.poses) < 2:
        return None
    try:
        s, fs = session, gyro_full_scale_dps(session.meta)
        return calibrate_gyro(s.t_s, s.gyro_dps, s.poses, s.temp_degC, full_scale_dps=fs)
    except ModelError as exc:  # e.g. a scale fit that did not converge: said, not silent
        note(f"gyro not calibrated: {exc}")
        return None
    except AccellogError:
        return None


# ------------------------------------------------------------------------------------------ evaluate / drift


def as_session(x: Session | StreamedSession | str | os.PathLike, what: str) -> Session:
    """The whole session of x (a StreamedSession: its file read whole); InputError for a pose table."""
    if isinstance(x, Session):
        return x
    s = load_input(x.path if isinstance(x, StreamedSession) else x)
    if not isinstance(s, Session):
        raise InputError(
            f"{what} needs a recorded session (samples), not a pose table / observations", where=str(x)
        )
    return s


def _cal(x: Calibration | str | os.PathLike) -> Calibration:
    return x if isinstance(x, Calibration) else load_calibration(x)


def run_evaluate(
    test: StaticInput,
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
    from accellog.flows.static_input import run_on_blocks
    from accellog.navigate.evaluate import evaluate_blocks, targets

    cals = [_cal(c) for c in cal] if isinstance(cal, (list, tuple)) else [_cal(cal)]
    tgts = targets(cals, labels, include_raw)
    evs, _data = run_on_blocks(
        test,
        lambda src: evaluate_blocks(src, tgts, times_s=times_s, until_s=until_s, max_samples=max_samples),
        lambda: as_session(test, "evaluate"),
        stream=stream,
    )
    return evs


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
    static: Session | str | os.PathLike,
    cal: Calibration | str | os.PathLike,
    *,
    until_s: float | None = None,
    max_samples: int | None = None,
    stream: bool = True,
) -> DriftOutcome:
    """Fit the displacement-drift model on a calibrated static session (an MCAP file: chunk by chunk)."""
    from accellog.flows.static_input import run_on_blocks
    from accellog.navigate.drift import drift_blocks

    c = _cal(cal)
    (cal_d, dm, ev), data = run_on_blocks(
        static,
        lambda src: drift_blocks(src, c, until_s=until_s, max_samples=max_samples),
        lambda: as_session(static, "drift"),
        stream=stream,
    )
    if isinstance(data, Session):
        entry = _source(data, None, "drift")
        if entry.recovered is not None:  # provenance: the drift was fitted on a recovered (truncated) file
            cal_d.sources = [*cal_d.sources, entry]
    return DriftOutcome(cal=cal_d, drift=dm, fit_eval=ev)
