"""accellog: record, calibrate and inspect cheap MEMS IMUs (MPU-9250).

Data flows one way (docs/architecture.md): device -> recorder -> MCAP -> stages -> calibration ->
reports / .rrd. The public API below is what a notebook needs; names load on first use, so
``import accellog`` stays fast::

    import accellog as al
    s = al.read_session("cal.mcap")                       # Session: t_s, accel_g, gyro_dps, temp_degC, poses
    obs = al.observations(s)                              # windowed hold means with autocorrelation-aware sigma
    fit = al.fit_model(obs, al.build_model("model3"))     # parameters with covariance, chi2
    cal = al.Calibration.from_fit(fit, obs=obs)
    cal.save("cal.json")
    print(al.diagnose(obs, al.build_model("model3")).verdict)
"""

from __future__ import annotations

import importlib
from typing import Any

from accellog.core.version import __version__

_API = {
    # core types
    "Session": "accellog.core.session",
    "SessionMeta": "accellog.core.session",
    "PoseLabel": "accellog.core.session",
    "ObsTable": "accellog.core.session",
    "AccellogError": "accellog.core.errors",
    "InputError": "accellog.core.errors",
    # store
    "read_session": "accellog.store.reader",
    "SessionWriter": "accellog.store.writer",
    "write_session": "accellog.store.writer",
    "import_csv": "accellog.store.importers",
    "import_capstone": "accellog.store.importers",
    "import_imucal": "accellog.store.importers",
    # calibrate
    "observations": "accellog.calibrate.segment",
    "detect_static": "accellog.calibrate.detect",
    "build_model": "accellog.calibrate.model",
    "fit_model": "accellog.calibrate.fit",
    "fit_orientation_free": "accellog.calibrate.fit",
    "Calibration": "accellog.calibrate.calibration",
    "load_calibration": "accellog.calibrate.calibration",
    "diagnose": "accellog.calibrate.diagnose",
    # navigate
    "evaluate": "accellog.navigate.evaluate",
    "evaluate_poses": "accellog.navigate.evaluate",
    "strapdown": "accellog.navigate.strapdown",
    # flows
    "Scenario": "accellog.flows.simulate",
    "simulate": "accellog.flows.simulate",
    "run_fit": "accellog.flows.stages",
    "run_pipeline": "accellog.flows.pipeline",
    "discover": "accellog.flows.workbench",
    # present
    "RunRecording": "accellog.present.rrd.recording",
}

__all__ = ["__version__", *sorted(_API)]


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
