"""Entity paths, timelines and colours of accellog recordings (tests and other stages rely on them).

- ``/{kind}/{name}``            (N,3) sample stream, e.g. ``/accel/raw``, ``/accel/calibrated`` (g)
- ``/poses/active/{k:02d}``     1 during hold k, 0 outside (step series, series name = pose label)
- ``/poses/log``                TextLog at each hold start: "hold k: <label> up (x, y, z)"
- ``/temperature``              die temperature (degC)
- ``/events``                   TextLog per Event; ``/events/lost_samples`` points (samples)
- ``/residuals/{model}/{axis}`` BarChart of measured - predicted per pose (mg), static;
  ``/residuals/{model}/measured|predicted|residual_mg`` on the ``pose`` sequence timeline
- ``/tracks/{label}``           displacement (N,3) in m on sensor_time
- ``/world/tracks/{label}``     LineStrips3D of the track (m), static; ``.../final`` Points3D
- ``/docs/{path}``              TextDocument (markdown), static
- ``/ladder/{metric}/{k:02d}_{model}`` BarChart of log10(metric) of ladder step k at abscissa k
  (metric in LADDER_METRICS; the entity name puts the model on its bar); ``/ladder/steps/{k:02d}/
  residual_mg`` residuals (mg) of step k in its own colour; ``/ladder/driver`` what they are plotted
  against (e.g. temperature, degC), once
- ``/charts/...``               the same residuals and ladder as 2D bar charts with named groups
- ``/live/...``                 live recording panels (prompt, stillness, running calibration)
"""

from __future__ import annotations

import re

import numpy as np

from accellog.core.errors import InputError

MAIN_TIMELINE = "sensor_time"
"""Duration timeline, s since session start (the sensor's sample clock)."""
SAMPLE_TIMELINE = "sample"
POSE_TIMELINE = "pose"
STEP_TIMELINE = "step"

POSES_ACTIVE = "poses/active"
POSES_LOG = "poses/log"
TEMPERATURE = "temperature"
EVENTS = "events"
EVENTS_LOST = "events/lost_samples"
RESIDUALS = "residuals"
TRACKS = "tracks"
WORLD_TRACKS = "world/tracks"
DOCS = "docs"
LADDER = "ladder"
# ladder bar charts: entity name -> view title (values are log10 of the metric)
LADDER_METRICS = {
    "log10_chi2_dof": "log10 χ²/dof (fit)",
    "log10_heldout_rms_mg": "log10 held-out RMS (mg)",
    "log10_drift_m": "log10 static-test drift (m)",
}
LIVE = "live"
CHARTS = "charts"
"""Root of the named 2D bar charts (present.rrd.bars2d): ``/charts/residuals/{model}`` (residual per
pose and axis, mg) and ``/charts/ladder`` (the ladder's metrics per step, log10)."""

AXES = ("x", "y", "z")
TRACK_3D_MAX_POINTS = 20_000
"""The 3D line strip of a track is decimated to at most this many points (last point kept)."""

DEFAULT_GRPC_URL = "rerun+http://127.0.0.1:9876/proxy"
SPAWN_PORT = 9876
"""Port of the native viewer started by the 'spawn' sink (bound to 127.0.0.1 only)."""

EVENT_LEVEL = {
    "gap": "WARN",
    "fifo_overflow": "WARN",
    "misaligned": "WARN",
    "i2c_error": "ERROR",
    "retry": "DEBUG",
    "recovered": "WARN",
    "note": "INFO",
    "pose_prompt": "INFO",
}

AXIS_COLORS = [(230, 80, 80), (80, 190, 80), (80, 130, 240)]
"""Series colours of the x, y, z axes in every plot (RGB)."""
TRACK_COLORS = [
    (240, 160, 40),
    (60, 170, 230),
    (200, 90, 200),
    (120, 200, 90),
    (230, 90, 90),
    (160, 160, 160),
]


def track_color(k: int) -> tuple[int, int, int]:
    """The colour of the k-th track of a recording (TRACK_COLORS in turn)."""
    return TRACK_COLORS[k % len(TRACK_COLORS)]


def slug(text: str) -> str:
    """Entity-path-safe form of a label: runs of other characters than letters, digits, '_', '-'
    and '.' become '_' ('cal A.json' -> 'cal_A.json')."""
    s = re.sub(r"[^A-Za-z0-9_.\-]+", "_", str(text).strip()).strip("_")
    return s or "unnamed"


def slug_path(label: str) -> str:
    """Entity sub-path of a label; '/' groups it ('test/Model 3' -> 'test/Model_3')."""
    return "/".join(slug(p) for p in str(label).split("/") if p.strip()) or "unnamed"


def as_2d(values: np.ndarray, n: int, what: str) -> np.ndarray:
    v = np.asarray(values, dtype=np.float64)
    if v.ndim == 1:
        v = v[:, None]
    if v.shape[0] != n:
        raise InputError(f"{what}: {v.shape[0]} rows for {n} time stamps")
    return v
