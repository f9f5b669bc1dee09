"""accellog: record, calibrate and inspect cheap MEMS IMUs (MPU-9250).

Data flows one way (docs/architecture.md): device -> recorder -> MCAP -> stages -> calibration ->
reports / .rrd. The public API below is what a notebook needs. Names load on first use, so
``import accellog`` (and every command's start-up) stays fast; type checkers read the same names
from the ``TYPE_CHECKING`` imports below, so they see the real types::

    import accellog as al
    s = al.read_session("cal.mcap")                       # Session: t_s, accel_g, gyro_dps, temp_degC, poses
    obs = al.observations(s)                              # windowed hold means with autocorrelation-aware sigma
    fit = al.fit_model(obs, al.build_model("model3"))     # parameters with covariance, chi2
    cal = al.Calibration.from_fit(fit, obs=obs)
    cal.save("cal.json")
    print(al.diagnose(obs, al.build_model("model3")).verdict)

A user effects file (``--effects-file``) starts ``from accellog import Effect, per_axis``: the stable
plugin API (docs/effects.md).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from accellog.core.version import __version__

if TYPE_CHECKING:  # the same names as _API, for type checkers (tests/cli/test_public_api.py checks both)
    from accellog.calibrate.calfile.calibration import Calibration, load_calibration
    from accellog.calibrate.diagnosis.diagnose import Diagnosis, diagnose
    from accellog.calibrate.model.compose import Model, build_model
    from accellog.calibrate.model.effects import Effect, Param, per_axis
    from accellog.calibrate.model.fit import FitResult, fit_model, fit_orientation_free
    from accellog.calibrate.observe.detect import detect_static
    from accellog.calibrate.observe.segment import observations
    from accellog.core.errors import AccellogError, DeviceError, InputError, ModelError
    from accellog.core.session import ObsTable, PoseLabel, Session, SessionMeta
    from accellog.flows.pipeline import run_pipeline
    from accellog.flows.simulate import Scenario, simulate
    from accellog.flows.stages import run_fit
    from accellog.flows.workbench import Discovery, discover
    from accellog.navigate.evaluate import evaluate, evaluate_poses
    from accellog.navigate.evaluation import Evaluation
    from accellog.navigate.strapdown import strapdown
    from accellog.present.rrd.recording import RunRecording
    from accellog.store.importers import import_capstone, import_csv, import_imucal, import_ros2
    from accellog.store.reader import read_session
    from accellog.store.writer import SessionWriter, write_session

_API = {
    # core types
    "Session": "accellog.core.session",
    "SessionMeta": "accellog.core.session",
    "PoseLabel": "accellog.core.session",
    "ObsTable": "accellog.core.session",
    "AccellogError": "accellog.core.errors",
    "InputError": "accellog.core.errors",
    "ModelError": "accellog.core.errors",
    "DeviceError": "accellog.core.errors",
    # store
    "read_session": "accellog.store.reader",
    "SessionWriter": "accellog.store.writer",
    "write_session": "accellog.store.writer",
    "import_csv": "accellog.store.importers",
    "import_capstone": "accellog.store.importers",
    "import_imucal": "accellog.store.importers",
    "import_ros2": "accellog.store.importers",
    # calibrate
    "observations": "accellog.calibrate.observe.segment",
    "detect_static": "accellog.calibrate.observe.detect",
    "Effect": "accellog.calibrate.model.effects",  # the effects-file API (stable: docs/effects.md)
    "Param": "accellog.calibrate.model.effects",
    "per_axis": "accellog.calibrate.model.effects",
    "build_model": "accellog.calibrate.model.compose",
    "Model": "accellog.calibrate.model.compose",
    "fit_model": "accellog.calibrate.model.fit",
    "fit_orientation_free": "accellog.calibrate.model.fit",
    "FitResult": "accellog.calibrate.model.fit",
    "Calibration": "accellog.calibrate.calfile.calibration",
    "load_calibration": "accellog.calibrate.calfile.calibration",
    "diagnose": "accellog.calibrate.diagnosis.diagnose",
    "Diagnosis": "accellog.calibrate.diagnosis.diagnose",
    # navigate
    "evaluate": "accellog.navigate.evaluate",
    "evaluate_poses": "accellog.navigate.evaluate",
    "Evaluation": "accellog.navigate.evaluation",
    "strapdown": "accellog.navigate.strapdown",
    # flows
    "Scenario": "accellog.flows.simulate",
    "simulate": "accellog.flows.simulate",
    "run_fit": "accellog.flows.stages",
    "run_pipeline": "accellog.flows.pipeline",
    "discover": "accellog.flows.workbench",
    "Discovery": "accellog.flows.workbench",
    # present
    "RunRecording": "accellog.present.rrd.recording",
}

__all__ = [
    "AccellogError",
    "Calibration",
    "DeviceError",
    "Diagnosis",
    "Discovery",
    "Effect",
    "Evaluation",
    "FitResult",
    "InputError",
    "Model",
    "ModelError",
    "ObsTable",
    "Param",
    "PoseLabel",
    "RunRecording",
    "Scenario",
    "Session",
    "SessionMeta",
    "SessionWriter",
    "__version__",
    "build_model",
    "detect_static",
    "diagnose",
    "discover",
    "evaluate",
    "evaluate_poses",
    "fit_model",
    "fit_orientation_free",
    "import_capstone",
    "import_csv",
    "import_imucal",
    "import_ros2",
    "load_calibration",
    "observations",
    "per_axis",
    "read_session",
    "run_fit",
    "run_pipeline",
    "simulate",
    "strapdown",
    "write_session",
]  # literal, so that tools read it; equal to _API's names (tests)


def __getattr__(name: str) -> Any:
    """Load a public name from its module on first use (PEP 562)."""
    module = _API.get(name)
    if module is None:
        raise AttributeError(f"module 'accellog' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return __all__
