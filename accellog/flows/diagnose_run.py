"""`accellog diagnose` as one library call: read the session, fit the model, rank what is missing.

A labelled session (MCAP streamed chunk by chunk when no .rrd is asked for, CSV, pose table or
observations JSON) goes to accellog.calibrate.diagnosis.diagnose with its observation windows, the host clock
and the held-out sessions; a session without pose labels (hand-held) to
accellog.calibrate.diagnosis.diagnose.diagnose_handheld on its detected static intervals (gravity-norm residual). The result is
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
from accellog.core.session import Session

if TYPE_CHECKING:
    from accellog.calibrate.diagnosis.diagnose import Diagnosis
    from accellog.calibrate.observe.detected_holds import Detection


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
    from accellog.calibrate.observe.obs_file import read_obs_table
    from accellog.store.source import open_source

    session = Path(session)
    if not session.is_file():
        raise InputError("session file not found", where=str(session))
    table = read_obs_table(session)  # observations JSON, pose tables
    src = None if table is not None else open_source(session, what="diagnose")
    if src is not None and not src.poses:
        return _handheld(
            src.whole(), session, model, add, effects_file, window_s, detect_window_s, threshold, heldout
        )
    if rrd is not None and src is not None:
        src.whole()  # the recording draws the samples
    return _labelled(
        table, src, session, model, add, effects_file, window_s, weighted, gravity_g, heldout, noise_from, rrd
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


def _sessions(paths: Sequence[str | Path]) -> Iterator[Session]:
    """The --heldout sessions one by one, whole (store.source.read_whole, imported only when there
    are some)."""
    if not paths:
        return
    from accellog.store.source import read_whole

    for h in paths:
        yield read_whole(h, what="--heldout")


def _labelled(
    table, src, session, model, add, effects_file, window_s, weighted, gravity_g, heldout, noise_from, rrd
) -> DiagnoseOutcome:
    """A labelled session (src: its observations and host clock points in one pass, read by a forked
    child while this process imports the diagnosis) or an observation table."""
    from accellog.calibrate.observe.segment import observations, observe_riding
    from accellog.store.stream import HostClock

    obs, host = table, None
    if src is not None:
        with started(observe_riding, src, window_s=window_s, rider=lambda _s: HostClock(),
                     what=f"reading {session}", meanwhile=not _diagnosis_loaded()) as reading:  # fmt: skip
            if reading.forked:
                _load_diagnosis()
            obs, clock, src = reading.result()
        host = clock.result() if clock is not None else None
    from accellog.calibrate.diagnosis import diagnose as dg
    from accellog.calibrate.model.compose import build_model

    m = build_model(model, add=list(add), effects_file=effects_file)
    helds = [observations(h, window_s=window_s) for h in _sessions(heldout)]
    if noise_from is not None:
        obs, helds = _noise_floored(obs, helds, src, noise_from)
    d = dg.diagnose(obs, m, weighted=weighted, gravity_g=gravity_g, host_time=host, heldout=helds)
    if rrd is not None:
        _write_rrd(rrd, src, d, obs)
    return DiagnoseOutcome(str(session), d)


def _noise_floored(obs, helds, src, noise_from):
    """Floor every window's sigma by the calibration's white noise (Allan) at the session's rate."""
    from accellog.calibrate.calfile.calibration import load_calibration
    from accellog.calibrate.noise.noise_model import floor_obs_sigma

    section = load_calibration(noise_from).noise
    if not section:
        raise InputError(
            "no noise section: add one with `accellog noise STILL.mcap --cal C -o C2`",
            where=str(noise_from),
        )
    rate = src.meta.sample_rate_hz if src is not None else None
    return floor_obs_sigma(obs, section, rate), [floor_obs_sigma(h, section, rate) for h in helds]


def _write_rrd(rrd, src, d, obs) -> None:
    from accellog.present.residual_views import log_diagnosis_residuals
    from accellog.present.rrd.recording import RunRecording
    from accellog.present.views import log_diagnosis, log_session

    with RunRecording(f"save:{rrd}") as rec:
        if src is not None:
            log_session(rec, src.whole())
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
    """An unlabelled session: detected static intervals, gravity-norm residual; the significant
    candidates judged out of sample on the gravity norm (held-out sessions, else blocks of the
    session: d.choice), by the workbench's ranking and tie rule."""
    from accellog.calibrate.diagnosis.strategy import NORM
    from accellog.calibrate.model.compose import build_model
    from accellog.calibrate.model.effects import HANDHELD_START
    from accellog.calibrate.observe.detected_holds import detect_holds, norm_obs

    name = HANDHELD_START if model == "model3" else model  # model3's cross_axis is not identifiable here
    m = build_model(name, add=list(add), effects_file=effects_file)
    obs, det = detect_holds(data, window_s=detect_window_s, threshold=threshold, obs_window_s=window_s)
    helds = [norm_obs(h, window_s=window_s) for h in _sessions(heldout)]
    d = NORM.diagnose(obs, m, heldout=helds)  # judged out of sample, as the workbench's steps are
    return DiagnoseOutcome(str(session), d, det)
