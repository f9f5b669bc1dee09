"""`accellog diagnose` as one library call: read the session, fit the model, rank what is missing.

A labelled session (MCAP streamed chunk by chunk when no .rrd is asked for, CSV, pose table or
observations JSON) goes to accellog.calibrate.diagnosis.diagnose with its observation windows, the host clock
and the held-out sessions; a session without pose labels (hand-held) to
accellog.calibrate.diagnosis.diagnose.diagnose_handheld on its detected static intervals (gravity-norm residual). The result is
typed (DiagnoseOutcome); the CLI only presents it.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from accellog.core.errors import InputError
from accellog.core.forked import started
from accellog.core.jsonio import JsonResult

if TYPE_CHECKING:
    from accellog.calibrate.diagnosis.diagnose import Diagnosis
    from accellog.calibrate.observe.detected_holds import Detection
    from accellog.store.source import Source


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
    """Diagnose one session file (module doc): what it holds is decided once (an observation
    table, labelled holds, or none: hand-held), then observe, diagnose. A labelled session's
    observations and host clock points come from one pass, read by a forked child while this
    process imports the diagnosis; a hand-held one is judged on its detected static intervals
    (gravity-norm residual, the significant candidates out of sample: held-out sessions, else blocks
    of the session). rrd: also write a Rerun recording of the residuals per pose, the verdict and
    the candidates (labelled sessions)."""
    from accellog.calibrate.observe.obs_file import read_obs_table
    from accellog.calibrate.observe.segment import observations, observe_riding
    from accellog.store.source import open_source, read_whole
    from accellog.store.stream import HostClock

    session = Path(session)
    if not session.is_file():
        raise InputError("session file not found", where=str(session))
    table = read_obs_table(session)  # observations JSON, pose tables
    src: Source | None = None
    host, det, handheld = None, None, False
    if table is not None:
        obs = table
    else:
        src = open_source(session, what="diagnose")
        handheld = not src.poses
        if handheld:
            from accellog.calibrate.observe.detected_holds import detect_holds

            obs, det = detect_holds(
                src.whole(), window_s=detect_window_s, threshold=threshold, obs_window_s=window_s
            )
        else:
            if rrd is not None:
                src.whole()  # the recording draws the samples
            with started(observe_riding, src, window_s=window_s, rider=HostClock.for_pass,
                         what=f"reading {session}", meanwhile=not _diagnosis_loaded()) as reading:  # fmt: skip
                if reading.forked:
                    _load_diagnosis()
                obs, clock, src = reading.result()
            host = clock.result() if clock is not None else None
    from accellog.calibrate.diagnosis import diagnose as dg
    from accellog.calibrate.diagnosis.strategy import NORM
    from accellog.calibrate.model.compose import build_model
    from accellog.calibrate.model.effects import HANDHELD_START
    from accellog.calibrate.observe.detected_holds import norm_obs

    name = HANDHELD_START if handheld and model == "model3" else model  # cross_axis needs labels
    m = build_model(name, add=list(add), effects_file=effects_file)
    if handheld:  # judged out of sample, as the workbench's steps are
        d = NORM.diagnose(
            obs, m, heldout=[norm_obs(read_whole(h, what="--heldout"), window_s=window_s) for h in heldout]
        )
        return DiagnoseOutcome(str(session), d, det)
    helds = [observations(read_whole(h, what="--heldout"), window_s=window_s) for h in heldout]
    if noise_from is not None:
        from accellog.calibrate.noise.noise_model import floor_noise

        rate = src.meta.sample_rate_hz if src is not None else None
        obs, helds = floor_noise(obs, helds, noise_from, rate)
    d = dg.diagnose(obs, m, weighted=weighted, gravity_g=gravity_g, host_time=host, heldout=helds)
    if rrd is not None:
        from accellog.present.residual_views import write_diagnosis_rrd

        write_diagnosis_rrd(rrd, None if src is None else src.whole(), d, obs)
    return DiagnoseOutcome(str(session), d)


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
