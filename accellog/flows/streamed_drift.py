"""The drift stage of an MCAP file chunk by chunk (``navigate.stream_drift``); other inputs (a loaded
Session, CSV, a damaged file, a model reading dT/dt) take the whole-session path of ``run_drift``."""

from __future__ import annotations

import os

from accellog.calibrate.calfile.calibration import Calibration
from accellog.calibrate.calfile.drift_model import DriftModel
from accellog.core.session import Session
from accellog.flows.stream_input import can_stream, open_streamed
from accellog.navigate.evaluate import Evaluation
from accellog.navigate.stream_drift import stream_drift


def streamed_drift(
    static: Session | str | os.PathLike,
    cal: Calibration,
    *,
    until_s: float | None = None,
    max_samples: int | None = None,
) -> tuple[Calibration, DriftModel, Evaluation] | None:
    """(cal + drift, drift, evaluation of the fit session after it), or None: not streamable."""
    if isinstance(static, Session) or not can_stream(static):
        return None
    s = open_streamed(static, observe=False, check_times=False)  # checked in the first drift pass
    if s is None:
        return None
    return stream_drift(s.path, s.meta, s.poses, cal, until_s=until_s, max_samples=max_samples)
