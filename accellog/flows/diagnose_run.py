"""`accellog diagnose` as one library call: read the session, fit the model, rank what is missing.

A labelled session (MCAP streamed chunk by chunk when no .rrd is asked for, CSV, pose table or
observations JSON) goes to accellog.calibrate.diagnosis.diagnose with its observation windows, the host clock
and the held-out sessions; a session without pose labels (hand-held) to
accellog.calibrate.diagnosis.handheld on its detected static intervals (gravity-norm residual). The result is
typed (DiagnoseOutcome); the CLI only presents it.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from accellog.core.errors import InputError
from accellog.core.forked import started
from accellog.core.jsonio import JsonResult
from accellog.core.session import ObsTable, Session

if TYPE_CHECKING:
    from accellog.calibrate.diagnosis.diagnose import Diagnosis
    from accellog.calibrate.diagnosis.handheld import Detection


@dataclass
class DiagnoseOutcome(JsonResult):
    """One diagnose run: the diagnosis of `session` and, for a hand-held session, the detection."""

    session: str
    diagnosis: Diagnosis
    detection: Detection | None = None
    """Detected static intervals (hand-held sessions only)."""

    @property
    def handheld(self) -> bool:
        return self.detection is not None

    def to_dict(self) -> dict:
        """diagnose --json: the diagnosis, the session and (hand-held) the detected intervals."""
        out = self.diagnosis.to_dict()
        if self.detection is None:
            out["session"] = self.session
        else:
            out.update(session=self.session, handheld=True, detected=self.detection.to_dict())
        return out


def run_diagnose(
    session: str | Path,
    *,
    model: str = "model3",
    add: Sequence[str] = (),
    effects_file: str | Path | None = None,
    window_s: float = 2.0,
    weighted: bool = True,
    gravity_g: float = 1.0,
    heldout: Sequence[str | Path] = (),
    detect_window_s: float = 1.0,
    threshold: float | None = None,
    noise_from: str | Path | None = None,
    rrd: str | Path | None = None,
) -> DiagnoseOutcome:
    """Diagnose one session file (module doc); rrd: also write a Rerun recording of the residuals
    per pose, the verdict and the candidates (labelled sessions)."""
    from accellog.flows.stream_input import open_labelled

    session = Path(session)
    if not session.is_file():
        raise InputError("session file not found", where=str(session))
    streamed = None
    if rrd is None:  # a forked child reads while this process imports the diagnosis (core.forked)
        with started(open_labelled, session, window_s=window_s, host=True, what=f"reading {session}",
                     meanwhile=not _diagnosis_loaded()) as reading:  # fmt: skip
            if reading.forked:
                _load_diagnosis()
            streamed = reading.result()
    data = streamed if streamed is not None else _load_whole(session)  # pose tables, observations: ObsTable
    if isinstance(data, Session) and not data.poses:
        return _handheld(
            data, session, model, add, effects_file, window_s, detect_window_s, threshold, heldout
        )
    return _labelled(
        data,
        streamed,
        session,
        model,
        add,
        effects_file,
        window_s,
        weighted,
        gravity_g,
        heldout,
        noise_from,
        rrd,
    )


def _diagnosis_loaded() -> bool:
    """Whether _load_diagnosis has nothing left to do (a second diagnosis in this process)."""
    from accellog.core.numeric import solver_loaded

    return solver_loaded() and "accellog.calibrate.diagnosis.diagnose" in sys.modules


def _load_diagnosis() -> None:
    """Import the diagnosis and its solver now, while a child reads: ~0.4 s of CPU (scipy.optimize,
    scipy.linalg) that otherwise follows the reading (figures: core.forked)."""
    import accellog.calibrate.diagnosis.diagnose  # noqa: F401
    from accellog.core.numeric import load_solver

    load_solver()


def _load_whole(session: Path):
    """The whole session (flows.stages.load_input), imported here: a streamed MCAP session does
    not load the stages' readers and importers (~0.12 s of CPU at start-up)."""
    from accellog.flows.stages import load_input

    return load_input(session)


def _sessions(paths: Sequence[str | Path]) -> Iterator[Session]:
    """The --heldout sessions one by one, whole (flows.stages.as_session, imported only when there
    are some)."""
    if not paths:
        return
    from accellog.flows.stages import as_session

    for h in paths:
        yield as_session(h, "--heldout")


def _labelled(
    data, streamed, session, model, add, effects_file, window_s, weighted, gravity_g, heldout, noise_from, rrd
) -> DiagnoseOutcome:
    from accellog.calibrate.diagnosis import diagnose as dg
    from accellog.calibrate.model.compose import build_model
    from accellog.calibrate.observe.segment import observations

    m = build_model(model, add=list(add), effects_file=effects_file)
    host = None
    if isinstance(data, ObsTable):
        obs = data
    elif streamed is not None:  # an MCAP session, chunk by chunk (bounded memory)
        obs, host = streamed.obs, streamed.host_clock
    else:
        obs = observations(data, window_s=window_s)
        if data.host_time_s is not None and np.all(np.isfinite(data.host_time_s)) and data.n > 2:
            host = (data.t_s, data.host_time_s)
    helds = [observations(h, window_s=window_s) for h in _sessions(heldout)]
    if noise_from is not None:
        obs, helds = _noise_floored(obs, helds, data, noise_from)
    d = dg.diagnose(obs, m, weighted=weighted, gravity_g=gravity_g, host_time=host, heldout=helds)
    if rrd is not None:
        _write_rrd(rrd, data, d, obs)
    return DiagnoseOutcome(str(session), d)


def _noise_floored(obs, helds, data, noise_from):
    """Floor every window's sigma by the calibration's white noise (Allan) at the session's rate."""
    from accellog.calibrate.calfile.calibration import load_calibration
    from accellog.calibrate.noise.noise_model import floor_obs_sigma

    section = load_calibration(noise_from).noise
    if not section:
        raise InputError(
            "no noise section: add one with `accellog noise STILL.mcap --cal C -o C2`",
            where=str(noise_from),
        )
    meta = getattr(data, "meta", None)
    rate = meta.sample_rate_hz if meta is not None else None
    return floor_obs_sigma(obs, section, rate), [floor_obs_sigma(h, section, rate) for h in helds]


def _write_rrd(rrd, data, d, obs) -> None:
    from accellog.present.residual_views import log_diagnosis_residuals
    from accellog.present.rrd.recording import RunRecording
    from accellog.present.views import log_diagnosis, log_session

    with RunRecording(f"save:{rrd}") as rec:
        if not isinstance(data, ObsTable):
            log_session(rec, data)
        log_diagnosis(rec, d, obs)
        log_diagnosis_residuals(rec, d, obs)
        rec.log_series(
            "residuals/windows",
            np.asarray(obs.t_s, float),
            np.asarray(d.fit.residual_g, float) * 1000.0,
            [f"{d.model.name} residual {a} (mg)" for a in "xyz"],
            points=True,
        )


def _handheld(
    data, session, model, add, effects_file, window_s, detect_window_s, threshold, heldout
) -> DiagnoseOutcome:
    """An unlabelled session: detected static intervals, gravity-norm residual; held-out sessions
    judge the significant candidates on their gravity norm (d.choice)."""
    from accellog.calibrate.diagnosis.handheld import (
        HANDHELD_START,
        detect_holds,
        diagnose_handheld,
        norm_choice,
        norm_obs,
    )
    from accellog.calibrate.model.compose import build_model

    name = HANDHELD_START if model == "model3" else model  # model3's cross_axis is not identifiable here
    m = build_model(name, add=list(add), effects_file=effects_file)
    obs, det = detect_holds(data, window_s=detect_window_s, threshold=threshold, obs_window_s=window_s)
    d = diagnose_handheld(obs, m)
    if heldout:
        helds = [norm_obs(h, window_s=window_s) for h in _sessions(heldout)]
        norm_choice(d, obs, helds)
    return DiagnoseOutcome(str(session), d, det)
