"""Rerun (.rrd) recordings of pipeline runs: arrays in, a recording laid out for the user's question.

``RunRecording`` knows nothing about files of accellog: the pipeline stages hand it numpy arrays
(samples, poses, residuals, tracks, documents) and it writes them columnar (``send_columns``, one
call per stream and batch, never per sample) on the main timeline ``sensor_time`` (duration, s
since session start) plus ``sample`` (sequence, device sample index) for raw streams.

Entity layout (module constants below; tests and other stages rely on it):

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
- ``/ladder/...``               model-building steps: tables, bar charts, residuals vs drivers
- ``/live/...``                 live recording panels (prompt, stillness, running calibration)

Sinks: ``save:PATH`` (file, written to a temporary name and renamed on ``close``), ``spawn``
(native viewer), ``connect`` / ``connect:URL`` (gRPC proxy, e.g.
``rerun+http://127.0.0.1:9876/proxy``). Live sinks are *guarded*: a failure is counted and
reported once, never raised into the caller (the MCAP recorder must keep recording).
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import socket
import sys
import threading
import time
import urllib.parse
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from accellog.core.errors import InputError
from accellog.core.session import Event, PoseLabel

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
LIVE = "live"

AXES = ("x", "y", "z")
TRACK_3D_MAX_POINTS = 20_000
"""The 3D line strip of a track is decimated to at most this many points (last point kept)."""

DEFAULT_GRPC_URL = "rerun+http://127.0.0.1:9876/proxy"
SPAWN_PORT = 9876
"""Port of the native viewer started by the 'spawn' sink (bound to 127.0.0.1 only)."""

_EVENT_LEVEL = {
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
_TRACK_COLORS = [
    (240, 160, 40),
    (60, 170, 230),
    (200, 90, 200),
    (120, 200, 90),
    (230, 90, 90),
    (160, 160, 160),
]


def slug(text: str) -> str:
    """Entity-path-safe form of a label: runs of other characters than letters, digits, '_', '-'
    and '.' become '_' ('cal A.json' -> 'cal_A.json')."""
    s = re.sub(r"[^A-Za-z0-9_.\-]+", "_", str(text).strip()).strip("_")
    return s or "unnamed"


def slug_path(label: str) -> str:
    """Entity sub-path of a label; '/' groups it ('test/Model 3' -> 'test/Model_3')."""
    return "/".join(slug(p) for p in str(label).split("/") if p.strip()) or "unnamed"


def _as_2d(values: np.ndarray, n: int, what: str) -> np.ndarray:
    v = np.asarray(values, dtype=np.float64)
    if v.ndim == 1:
        v = v[:, None]
    if v.shape[0] != n:
        raise InputError(f"{what}: {v.shape[0]} rows for {n} time stamps")
    return v


@dataclass
class LadderRow:
    """One model-building step of the workbench ladder.

    chi2_dof: chi^2 / degrees of freedom of the fit; heldout_rms_mg: RMS of held-out residuals (mg);
    drift_60s_m: |displacement| after 60 s of the static test integrated with this model (m).
    t_s / residual_g: residuals of the static windows (s, (n,3) g) left by this step; driver: the
    signal (e.g. temperature in degC) that the *next* effect explains, sampled at t_s.
    """

    step: str
    added: str = ""
    chi2_dof: float = math.nan
    heldout_rms_mg: float = math.nan
    drift_60s_m: float = math.nan
    t_s: np.ndarray | None = None
    residual_g: np.ndarray | None = None
    driver_name: str = ""
    driver: np.ndarray | None = None
    extra: dict[str, float] = field(default_factory=dict)


class _SinkWatch:
    """Background TCP probe of a live sink (host, port): marks it down once unreachable."""

    def __init__(self, host: str, port: int, on_down: Callable[[str], None], period_s: float = 0.25):
        self.host, self.port, self.on_down, self.period_s = host, port, on_down, period_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="accellog-rerun-watch", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        misses = 0
        while not self._stop.wait(self.period_s):
            try:
                with socket.create_connection((self.host, self.port), timeout=0.5):
                    misses = 0
            except OSError as exc:
                misses += 1
                if misses >= 2:
                    self.on_down(f"viewer at {self.host}:{self.port} unreachable ({exc.strerror or exc})")
                    return

    def stop(self) -> None:
        self._stop.set()


def _spawn_viewer(port: int, timeout_s: float = 20.0) -> None:
    """Start the native viewer listening on 127.0.0.1:port (``rr.spawn`` would bind 0.0.0.0), unless
    a viewer already listens there; wait until it accepts connections."""
    import subprocess

    from accellog.present.viewer import rerun_binary, rerun_env

    if wait_for_port("127.0.0.1", port, 0.0):
        return
    cmd = [rerun_binary(), "--bind", "127.0.0.1", "--port", str(port), "--expect-data-soon"]
    subprocess.Popen(
        cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=rerun_env(), start_new_session=True
    )
    if not wait_for_port("127.0.0.1", port, timeout_s):
        raise InputError(f"the spawned viewer does not listen on 127.0.0.1:{port} after {timeout_s:g} s")


def _parse_sink(sink: str) -> tuple[str, str]:
    if sink.startswith("save:"):
        path = sink[5:]
        if not path:
            raise InputError("rerun sink 'save:' needs a file name, e.g. save:run.rrd")
        return "save", path
    if sink == "spawn":
        return "spawn", ""
    if sink == "connect":
        return "connect", DEFAULT_GRPC_URL
    if sink.startswith("connect:"):
        return "connect", sink[8:]
    raise InputError(f"unknown rerun sink {sink!r}: use save:FILE.rrd, spawn, connect or connect:URL")


class RunRecording:
    """A Rerun recording of one pipeline run (see the module docstring for the entity layout).

    sink: 'save:PATH' | 'spawn' | 'connect' | 'connect:URL'. blueprint: 'auto' (a layout built on
    close from what was logged; live sinks get the full standard layout up front), None (no
    blueprint), or an ``rrb.Blueprint``. guard: catch and count logging failures instead of raising
    (default: True for live sinks, False for files). on_failure: called once with a one-line
    message at the first failure (default: print to stderr).
    """

    def __init__(
        self,
        sink: str,
        *,
        app_id: str = "accellog",
        recording_id: str | None = None,
        blueprint: Any = "auto",
        guard: bool | None = None,
        on_failure: Callable[[str], None] | None = None,
    ) -> None:
        import rerun as rr

        self.kind, self.target = _parse_sink(sink)
        self.guard = (self.kind != "save") if guard is None else guard
        self.failures = 0
        self.first_failure: str | None = None
        self.down = False
        self._on_failure = on_failure or (lambda msg: print(f"accellog: warning: {msg}", file=sys.stderr))
        self._blueprint = blueprint
        self._entities: dict[str, str] = {}  # entity path -> role, drives the auto blueprint
        self._closed = False
        self._watch: _SinkWatch | None = None
        self._tmp: Path | None = None
        self._final: Path | None = None
        self._lock = threading.Lock()
        self._n_tracks = 0
        self._n_poses = 0  # holds logged so far: /poses/active/{k} numbers them across calls
        self.rec = rr.RecordingStream(app_id, recording_id=recording_id, send_properties=False)
        with contextlib.suppress(AttributeError):
            self.rec.set_log_time_enabled(False)  # reproducible files: no wall-clock timeline
        bp = self._initial_blueprint()
        if self.kind == "save":
            self._final = Path(self.target)
            if self._final.parent and not self._final.parent.exists():
                raise InputError("folder does not exist", where=str(self._final.parent))
            self._tmp = self._final.with_name(f".{self._final.name}.{os.getpid()}.tmp")
            self.rec.save(str(self._tmp), default_blueprint=bp)
        else:
            self._guarded(self._connect, bp)

    # -- sinks ---------------------------------------------------------------------------------------
    def _initial_blueprint(self):
        if self._blueprint is None:
            return None
        if isinstance(self._blueprint, str):
            return live_blueprint() if self.kind != "save" else None
        return self._blueprint

    def _connect(self, bp) -> None:
        if self.kind == "spawn":
            host, port = "127.0.0.1", SPAWN_PORT
            _spawn_viewer(port)
            self.rec.connect_grpc(f"rerun+http://{host}:{port}/proxy", default_blueprint=bp)
        else:
            self.rec.connect_grpc(self.target, default_blueprint=bp)
            u = urllib.parse.urlparse(self.target.replace("rerun+", "", 1))
            host, port = u.hostname or "127.0.0.1", u.port or 9876
        self._watch = _SinkWatch(host, port, self._sink_down)

    def _sink_down(self, msg: str) -> None:
        self.down = True
        self._fail(msg + "; live view stopped, recording continues")

    def _fail(self, msg: str) -> None:
        with self._lock:
            self.failures += 1
            first = self.first_failure is None
            if first:
                self.first_failure = msg
        if first:
            with contextlib.suppress(Exception):
                self._on_failure(msg)

    def _guarded(self, fn: Callable[..., Any], *args: Any, **kw: Any) -> Any:
        if self._closed:
            return None
        if not self.guard:
            return fn(*args, **kw)
        if self.down:
            self.failures += 1
            return None
        try:
            return fn(*args, **kw)
        except Exception as exc:  # a live view must never stop the caller
            self._fail(f"live view failed: {type(exc).__name__}: {exc}")
            return None

    # -- generic -------------------------------------------------------------------------------------
    def log_series(
        self,
        entity: str,
        t_s: np.ndarray,
        values: np.ndarray,
        names: Sequence[str],
        *,
        sample_index: np.ndarray | None = None,
        role: str = "series",
        colors: Sequence[tuple[int, int, int]] | None = None,
        points: bool = False,
        step: bool = False,
    ) -> None:
        """Columnar scalars (N,k) on sensor_time (and ``sample`` if given); names label the k series."""
        self._guarded(self._log_series, entity, t_s, values, names, sample_index, role, colors, points, step)

    def _log_series(self, entity, t_s, values, names, sample_index, role, colors, points, step) -> None:
        import rerun as rr

        t = np.asarray(t_s, dtype=np.float64)
        v = _as_2d(values, t.shape[0], entity)
        if entity not in self._entities:
            self._entities[entity] = role
            style: dict[str, Any] = {"names": list(names)}
            if colors is not None:
                style["colors"] = list(colors)
            if points:
                self.rec.log(entity, rr.SeriesPoints(**style), static=True)
            else:
                if step:
                    style["interpolation_mode"] = rr.components.InterpolationMode.StepAfter
                self.rec.log(entity, rr.SeriesLines(**style), static=True)
        if t.shape[0] == 0:
            return
        idx = [rr.TimeColumn(MAIN_TIMELINE, duration=t)]
        if sample_index is not None:
            idx.append(rr.TimeColumn(SAMPLE_TIMELINE, sequence=np.asarray(sample_index, dtype=np.int64)))
        cols = v[:, 0] if v.shape[1] == 1 else v
        self.rec.send_columns(entity, indexes=idx, columns=rr.Scalars.columns(scalars=cols))

    # -- pipeline data -------------------------------------------------------------------------------
    def log_samples(
        self,
        name: str,
        t_s: np.ndarray,
        sample_index: np.ndarray | None,
        values: np.ndarray,
        unit: str,
        kind: str = "accel",
    ) -> None:
        """Sample stream (N,3) at ``/{kind}/{name}``, e.g. raw or calibrated accel in g (unit 'g')."""
        entity = f"{slug(kind)}/{slug(name)}"
        names = [f"{name} {a} ({unit})" for a in AXES]
        self.log_series(
            entity, t_s, values, names, sample_index=sample_index, role=f"samples:{kind}", colors=AXIS_COLORS
        )

    def log_poses(self, poses: Sequence[PoseLabel]) -> None:
        """Hold windows: a 0/1 step series per hold (named by its label) + a TextLog at each start.

        Holds are numbered in logging order across calls (k = 0, 1, ... at ``/poses/active/{k:02d}``)."""
        self._guarded(self._log_poses, list(poses))

    def _log_poses(self, poses: list[PoseLabel]) -> None:
        import rerun as rr

        if not poses:
            return
        k0 = self._n_poses
        self._n_poses += len(poses)
        for k, p in enumerate(poses, start=k0):
            t = np.array([p.start_s, p.end_s], dtype=np.float64)
            self._log_series(
                f"{POSES_ACTIVE}/{k:02d}",
                t,
                np.array([1.0, 0.0]),
                [f"pose {p.name}"],
                None,
                "poses",
                [(150, 150, 150)],
                False,
                True,
            )
        t = np.array([p.start_s for p in poses], dtype=np.float64)
        texts = [
            f"hold {p.hold_index}: {p.name} up ({p.up_sensor[0]:+.0f}, {p.up_sensor[1]:+.0f}, "
            f"{p.up_sensor[2]:+.0f}) {p.start_s:.2f}-{p.end_s:.2f} s"
            for p in poses
        ]
        self._entities[POSES_LOG] = "textlog"
        self.rec.send_columns(
            POSES_LOG,
            indexes=[rr.TimeColumn(MAIN_TIMELINE, duration=t)],
            columns=rr.TextLog.columns(text=texts, level=["INFO"] * len(texts)),
        )

    def log_temperature(self, t_s: np.ndarray, temp_degC: np.ndarray) -> None:
        """Die temperature (degC) on sensor_time."""
        self.log_series(TEMPERATURE, t_s, temp_degC, ["die temperature (degC)"], role="temperature")

    def log_events(self, events: Iterable[Event]) -> None:
        """Every event as a TextLog line (level by kind) + lost samples as points on sensor_time."""
        self._guarded(self._log_events, list(events))

    def _log_events(self, events: list[Event]) -> None:
        import rerun as rr

        if not events:
            return
        events = sorted(events, key=lambda e: e.t_s)
        t = np.array([e.t_s for e in events], dtype=np.float64)
        texts = [
            f"{e.kind}: {e.detail}"
            + (f" (sample {e.sample_index})" if e.sample_index >= 0 else "")
            + (f", {e.lost_samples} samples lost" if e.lost_samples else "")
            for e in events
        ]
        levels = [_EVENT_LEVEL.get(e.kind, "INFO") for e in events]
        self._entities[EVENTS] = "textlog"
        self.rec.send_columns(
            EVENTS,
            indexes=[rr.TimeColumn(MAIN_TIMELINE, duration=t)],
            columns=rr.TextLog.columns(text=texts, level=levels),
        )
        lost = np.array([e.lost_samples for e in events], dtype=np.float64)
        m = lost > 0
        if m.any():
            self._log_series(
                EVENTS_LOST, t[m], lost[m], ["lost samples"], None, "lost", [(240, 60, 60)], True, False
            )

    def log_residuals(
        self,
        model_name: str,
        pose_names: Sequence[str],
        measured_g: np.ndarray,
        predicted_g: np.ndarray,
    ) -> None:
        """What a model predicts next to what was measured, per pose and axis.

        residual = measured - predicted (mg). Written as one static BarChart per axis (x position =
        pose index, order of pose_names), measured/predicted/residual series on the ``pose``
        timeline, and a markdown table ``/docs/residuals/{model}``.
        """
        self._guarded(self._log_residuals, model_name, list(pose_names), measured_g, predicted_g)

    def _log_residuals(self, model_name, pose_names, measured_g, predicted_g) -> None:
        import rerun as rr

        meas = np.asarray(measured_g, dtype=np.float64).reshape(-1, 3)
        pred = np.asarray(predicted_g, dtype=np.float64).reshape(-1, 3)
        if meas.shape != pred.shape or meas.shape[0] != len(pose_names):
            raise InputError(
                f"residuals of {model_name!r}: {len(pose_names)} poses, measured {meas.shape}, "
                f"predicted {pred.shape}"
            )
        res_mg = (meas - pred) * 1000.0
        base = f"{RESIDUALS}/{slug(model_name)}"
        pos = np.arange(len(pose_names), dtype=np.float64)
        for k, a in enumerate(AXES):  # grouped bars: pose i at i-0.25 (x), i (y), i+0.25 (z)
            ent = f"{base}/{a}"
            self._entities[ent] = "residual_bar"
            self.rec.log(
                ent,
                rr.BarChart(res_mg[:, k], color=AXIS_COLORS[k], abscissa=pos + 0.25 * (k - 1), widths=[0.25]),
                static=True,
            )
        self.rec.log(base, rr.AnyValues(pose=list(pose_names)), static=True)
        idx = [rr.TimeColumn(POSE_TIMELINE, sequence=np.arange(len(pose_names)))]
        for sub, arr, unit in (
            ("measured", meas, "g"),
            ("predicted", pred, "g"),
            ("residual_mg", res_mg, "mg"),
        ):
            ent = f"{base}/{sub}"
            self._entities[ent] = "residual_series"
            self.rec.log(ent, rr.SeriesPoints(names=[f"{sub} {a} ({unit})" for a in AXES]), static=True)
            self.rec.send_columns(ent, indexes=idx, columns=rr.Scalars.columns(scalars=arr))
        rows = [
            "| pose | " + " | ".join(f"meas {a} (g) | pred {a} (g) | res {a} (mg)" for a in AXES) + " |",
            "|---|" + "---|" * 9,
        ]
        for i, name in enumerate(pose_names):
            cells = " | ".join(
                f"{meas[i, k]:+.5f} | {pred[i, k]:+.5f} | {res_mg[i, k]:+.2f}" for k in range(3)
            )
            rows.append(f"| {name} | {cells} |")
        rms = np.sqrt(np.mean(res_mg**2, axis=0))
        rows.append("| **RMS** | " + " | ".join(f" | | {rms[k]:.2f}" for k in range(3)) + " |")
        md = f"### Residuals of {model_name} (measured - predicted)\n\n" + "\n".join(rows) + "\n"
        self._log_document(f"residuals/{model_name}", md)

    def log_track(self, label: str, t_s: np.ndarray, disp_m: np.ndarray) -> None:
        """Displacement track (N,3) in m: time series ``/tracks/{label}`` and a 3D line strip
        ``/world/tracks/{label}`` with its final point (labelled with the final displacement)."""
        self._guarded(self._log_track, label, t_s, disp_m)

    def _log_track(self, label: str, t_s: np.ndarray, disp_m: np.ndarray) -> None:
        d = np.asarray(disp_m, dtype=np.float64).reshape(-1, 3)
        color = _TRACK_COLORS[self._n_tracks % len(_TRACK_COLORS)]
        if f"{TRACKS}/{slug_path(label)}" not in self._entities:
            self._n_tracks += 1
        name = str(label).rsplit("/", 1)[-1]
        self._log_series(
            f"{TRACKS}/{slug_path(label)}",
            t_s,
            d,
            [f"{name} {a} (m)" for a in AXES],
            None,
            "track",
            AXIS_COLORS,
            False,
            False,
        )
        if d.shape[0]:
            self._log_track_3d(label, d, color)

    def log_track_3d(
        self, label: str, disp_m: np.ndarray, *, color: tuple[int, int, int] | None = None
    ) -> None:
        """Static 3D line strip of a whole track (m; decimated, last point kept) + its final point."""
        self._guarded(self._log_track_3d, label, disp_m, color)

    def _log_track_3d(self, label: str, disp_m: np.ndarray, color: tuple[int, int, int] | None) -> None:
        import rerun as rr

        d = np.asarray(disp_m, dtype=np.float64).reshape(-1, 3)
        color = color or _TRACK_COLORS[0]
        n = d.shape[0]
        if n > TRACK_3D_MAX_POINTS:
            keep = np.unique(np.r_[np.linspace(0, n - 1, TRACK_3D_MAX_POINTS).astype(np.int64), n - 1])
            d_strip = d[keep]
        else:
            d_strip = d
        ent = f"{WORLD_TRACKS}/{slug_path(label)}"
        self._entities[ent] = "track3d"
        final = d[-1]
        label = str(label).rsplit("/", 1)[-1]
        self.rec.log(ent, rr.LineStrips3D([d_strip], colors=[color], labels=[label]), static=True)
        self.rec.log(
            f"{ent}/final",
            rr.Points3D(
                [final],
                colors=[color],
                radii=[-6.0],  # negative radius = screen-space points (ui points)
                labels=[f"{label}: ({final[0]:+.3g}, {final[1]:+.3g}, {final[2]:+.3g}) m"],
            ),
            static=True,
        )

    def log_document(self, path: str, markdown: str) -> None:
        """A markdown document (tables, parameters with uncertainties) at ``/docs/{path}``."""
        self._guarded(self._log_document, path, markdown)

    def _log_document(self, path: str, markdown: str) -> None:
        import rerun as rr

        ent = f"{DOCS}/" + "/".join(slug(p) for p in str(path).split("/") if p)
        self._entities[ent] = "doc"
        self.rec.log(ent, rr.TextDocument(markdown, media_type=rr.MediaType.MARKDOWN), static=True)

    def _log_document_at(self, entity: str, markdown: str) -> None:
        import rerun as rr

        self._entities.setdefault(entity, "doc")
        self.rec.log(entity, rr.TextDocument(markdown, media_type=rr.MediaType.MARKDOWN), static=True)

    def log_ladder(self, rows: Sequence[LadderRow | Mapping[str, Any]]) -> None:
        """Model-building steps: a table (chi2/dof, held-out RMS, 60 s drift), one bar chart per
        metric over the steps, and per step its residuals (mg) next to the driver that explains them."""
        self._guarded(self._log_ladder, [r if isinstance(r, LadderRow) else LadderRow(**r) for r in rows])

    def _log_ladder(self, rows: list[LadderRow]) -> None:
        import rerun as rr

        if not rows:
            return
        md = [
            "### Model ladder\n",
            "| # | step | added | chi2/dof | held-out RMS (mg) | drift 60 s (m) |",
            "|---|---|---|---|---|---|",
        ]
        for i, r in enumerate(rows):
            md.append(
                f"| {i} | {r.step} | {r.added} | {r.chi2_dof:.3g} | {r.heldout_rms_mg:.3g} | {r.drift_60s_m:.3g} |"
            )
        self._log_document("ladder", "\n".join(md) + "\n")
        for metric in ("chi2_dof", "heldout_rms_mg", "drift_60s_m"):
            ent = f"{LADDER}/{metric}"
            self._entities[ent] = "ladder_bar"
            vals = np.array([getattr(r, metric) for r in rows], dtype=np.float64)
            self.rec.log(ent, rr.BarChart(vals), static=True)
        self.rec.log(
            LADDER, rr.AnyValues(step=[r.step for r in rows], added=[r.added for r in rows]), static=True
        )
        for i, r in enumerate(rows):
            if r.t_s is None or r.residual_g is None:
                continue
            base = f"{LADDER}/steps/{i:02d}"
            t = np.asarray(r.t_s, dtype=np.float64)
            self._log_series(
                f"{base}/residual_mg",
                t,
                np.asarray(r.residual_g, dtype=np.float64).reshape(-1, 3) * 1000.0,
                [f"{i} {r.step} res {a} (mg)" for a in AXES],
                None,
                "ladder_step",
                AXIS_COLORS,
                True,
                False,
            )
            if r.driver is not None:
                self._log_series(
                    f"{base}/driver",
                    t,
                    np.asarray(r.driver, dtype=np.float64),
                    [f"driver {r.driver_name}"],
                    None,
                    "ladder_step",
                    [(120, 120, 120)],
                    False,
                    False,
                )

    def log_text(self, entity: str, t_s: float, text: str, level: str = "INFO") -> None:
        """One TextLog line at sensor time t_s."""
        self._guarded(self._log_text, entity, t_s, text, level)

    def _log_text(self, entity: str, t_s: float, text: str, level: str) -> None:
        import rerun as rr

        self._entities.setdefault(entity, "textlog")
        self.rec.set_time(MAIN_TIMELINE, duration=float(t_s))
        self.rec.log(entity, rr.TextLog(text, level=level))

    # -- finish --------------------------------------------------------------------------------------
    @property
    def entities(self) -> dict[str, str]:
        """Entity paths logged so far -> role."""
        return dict(self._entities)

    def report(self) -> str | None:
        """One line describing live-view failures, or None when there were none."""
        if not self.failures:
            return None
        return f"live view: {self.failures} logging calls dropped ({self.first_failure})"

    def close(self) -> None:
        """Send the blueprint, flush and finish the sink; a file is renamed into place only now."""
        if self._closed:
            return
        if self._watch is not None:
            self._watch.stop()
        try:
            if self._blueprint == "auto" and self.kind == "save":
                self.rec.send_blueprint(build_blueprint(self._entities), make_active=True, make_default=True)
            if self.kind == "save":
                self.rec.flush()
                self.rec.disconnect()
            else:
                self._guarded(self.rec.flush, timeout_sec=2.0)
                self._guarded(self.rec.disconnect)
        except BaseException:
            self.abort()  # no half-written file left behind
            raise
        finally:
            self._closed = True
        if self._tmp is not None and self._final is not None:
            os.replace(self._tmp, self._final)

    def abort(self) -> None:
        """Stop without producing a file (a temporary file is removed)."""
        if self._watch is not None:
            self._watch.stop()
        if not self._closed:
            self._closed = True
            with contextlib.suppress(Exception):
                self.rec.disconnect()
        if self._tmp is not None:
            with contextlib.suppress(FileNotFoundError):
                self._tmp.unlink()

    def __enter__(self) -> RunRecording:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


# -- blueprints --------------------------------------------------------------------------------------
def time_panel():
    """Time panel on sensor_time, following new data, collapsed (shared by every blueprint)."""
    import rerun.blueprint as rrb

    return rrb.TimePanel(timeline=MAIN_TIMELINE, play_state="following", state="collapsed")


def build_blueprint(entities: Mapping[str, str]):
    """Layout for what was logged: sample streams with pose windows, temperature + events, tracks
    (time series + 3D side by side), residual and ladder charts, documents and logs. With two or
    more tracks (replay, compare) the tracks take the main area, one auto-scaled plot each."""
    import rerun.blueprint as rrb

    roles: dict[str, list[str]] = {}
    for ent, role in entities.items():
        roles.setdefault(role, []).append(ent)
    has_poses = "poses" in roles
    samples = []
    for ent in [e for r, es in roles.items() if r.startswith("samples:") for e in es]:  # logged order
        contents = ["$origin/**"] + ([f"/{POSES_ACTIVE}/**"] if has_poses else [])
        samples.append(rrb.TimeSeriesView(origin=f"/{ent}", contents=contents, name=ent.replace("/", " ")))
    if "temperature" in roles or "lost" in roles:
        samples.append(
            rrb.TimeSeriesView(
                origin="/",
                contents=[f"/{TEMPERATURE}", f"/{EVENTS_LOST}"],
                name="temperature (degC) + lost samples",
            )
        )
    tracks = roles.get("track", [])  # logged order (raw first in replays)
    track_views = [rrb.TimeSeriesView(origin=f"/{e}", name=f"{e.split('/', 1)[1]} (m)") for e in tracks]
    world = rrb.Spatial3DView(origin="/world", name="tracks 3D (m)") if "track3d" in roles else None
    charts = []
    for model in sorted({e.split("/")[1] for e in roles.get("residual_bar", [])}):
        charts.append(rrb.BarChartView(origin=f"/{RESIDUALS}/{model}", name=f"residuals {model} (mg)"))
    if "ladder_bar" in roles:
        charts.append(
            rrb.Horizontal(
                *[
                    rrb.BarChartView(origin=f"/{LADDER}/{m}", name=m)
                    for m in ("chi2_dof", "heldout_rms_mg", "drift_60s_m")
                ],
                name="model ladder",
            )
        )
    if "ladder_step" in roles:
        charts.append(rrb.TimeSeriesView(origin=f"/{LADDER}/steps", name="ladder residuals (mg) vs driver"))
    texts = [
        rrb.TextDocumentView(origin=f"/{e}", name=e[len(DOCS) + 1 :]) for e in sorted(roles.get("doc", []))
    ]
    if "textlog" in roles:
        texts.append(rrb.TextLogView(origin="/", name="events and poses"))

    def group(views, kind=rrb.Vertical):
        views = [v for v in views if v is not None]
        if not views:
            return None
        return views[0] if len(views) == 1 else kind(*views)

    if len(track_views) >= 2:  # replay / compare: the tracks are the question
        top = [rrb.Grid(*track_views, name="displacement per track"), group([world, group(texts, rrb.Tabs)])]
        rows = [rrb.Horizontal(*[c for c in top if c is not None], column_shares=[3, 2])]
        bottom = group([*samples, *charts], rrb.Tabs)
        if bottom is not None:
            rows.append(bottom)
        root = rows[0] if len(rows) == 1 else rrb.Vertical(*rows, row_shares=[3, 1])
    else:
        left = group(samples if len(samples) <= 3 else [rrb.Tabs(*samples[:-1]), samples[-1]])
        right = group(
            [
                group([*track_views, world], rrb.Horizontal),
                group(charts, rrb.Tabs),
                group(texts, rrb.Tabs),
            ]
        )
        cols = [c for c in (left, right) if c is not None]
        root = (
            rrb.Horizontal(*cols, column_shares=[3, 2])
            if len(cols) == 2
            else (cols[0] if cols else rrb.Vertical())
        )
    return rrb.Blueprint(root, time_panel(), collapse_panels=True)


def live_blueprint():
    """Standard layout for a live recording (views appear as their data arrives)."""
    import rerun.blueprint as rrb

    poses = f"/{POSES_ACTIVE}/**"
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.TimeSeriesView(origin="/accel/raw", contents=["$origin/**", poses], name="accel raw (g)"),
                rrb.TimeSeriesView(
                    origin="/accel/calibrated", contents=["$origin/**", poses], name="accel calibrated (g)"
                ),
                rrb.TimeSeriesView(origin=f"/{LIVE}/stillness", name="stillness"),
                rrb.TimeSeriesView(
                    origin="/", contents=[f"/{TEMPERATURE}", f"/{EVENTS_LOST}"], name="temperature"
                ),
            ),
            rrb.Vertical(
                rrb.TextDocumentView(origin=f"/{LIVE}/prompt", name="next pose"),
                rrb.Horizontal(
                    rrb.TimeSeriesView(origin=f"/{TRACKS}", name="displacement (m)"),
                    rrb.Spatial3DView(origin="/world", name="tracks 3D (m)"),
                ),
                rrb.Tabs(
                    rrb.TextDocumentView(origin=f"/{LIVE}/calibration", name="running calibration"),
                    rrb.TextLogView(origin="/", name="events and poses"),
                ),
            ),
            column_shares=[3, 2],
        ),
        time_panel(),
        collapse_panels=True,
    )


class LiveView:
    """Live panels for a guided recording, on top of a guarded RunRecording.

    Implements the recorder's ``RecorderUI`` (prompt/waiting/holding/finished_pose) and its
    ``on_batch(batch, accel_g)`` callback. Every call is guarded: a closed or unreachable viewer
    is counted (``failures``) and reported once, never raised into the recording loop.
    """

    def __init__(self, recording: RunRecording | str, *, integrate: bool = False) -> None:
        self.run = recording if isinstance(recording, RunRecording) else RunRecording(recording, guard=True)
        self.run.guard = True
        self._t_s = 0.0
        self._integrator = None
        if integrate:
            from accellog.navigate.online import OnlineIntegrator

            self._integrator = OnlineIntegrator()

    @classmethod
    def from_option(cls, option: str, *, integrate: bool = False) -> LiveView:
        """From a CLI option: 'spawn', 'connect', 'connect URL', 'connect:URL', 'save FILE.rrd',
        'save:FILE.rrd' or a path ending in .rrd."""
        opt = option.strip()
        head, _, rest = opt.partition(" ")
        if head in ("connect", "save") and rest.strip():
            opt = f"{head}:{rest.strip()}"
        elif opt.endswith(".rrd") and not opt.startswith(("save:", "connect:")):
            opt = f"save:{opt}"
        return cls(RunRecording(opt, guard=True), integrate=integrate)

    def wrap_ui(self, ui):
        """A RecorderUI that forwards every call to ``ui`` (the terminal) and then to this view."""
        return _TeeUI(ui, self)

    @property
    def failures(self) -> int:
        return self.run.failures

    def pose_prompt(
        self, name: str, up: Sequence[float], *, index: int | None = None, total: int | None = None
    ) -> None:
        """Show the next pose to set (markdown panel + a log line)."""
        head = f"pose {index + 1}/{total}: " if index is not None and total else "next pose: "
        md = f"## {head}**{name}**\n\nturn the sensor so that ({up[0]:+.0f}, {up[1]:+.0f}, {up[2]:+.0f}) points up"
        self.run._guarded(self.run._log_document_at, f"{LIVE}/prompt", md)
        self.run.log_text(f"{LIVE}/log", self._t_s, head + name)

    def stillness(self, t_s: float, still: bool, stat: float) -> None:
        """Stillness detector state at sensor time t_s: still (0/1) and its statistic."""
        self._t_s = max(self._t_s, float(t_s))
        self.run.log_series(
            f"{LIVE}/stillness",
            np.array([t_s], dtype=np.float64),
            np.array([[1.0 if still else 0.0, float(stat)]]),
            ["still (0/1)", "motion statistic"],
            role="live",
        )

    def running_calibration(self, text: str) -> None:
        """Markdown of the calibration fitted so far."""
        self.run._guarded(self.run._log_document_at, f"{LIVE}/calibration", text)

    def log_batch(
        self,
        t_s: np.ndarray,
        sample_index: np.ndarray | None,
        accel_g: np.ndarray,
        *,
        temp_degC: np.ndarray | None = None,
        calibrated_g: np.ndarray | None = None,
    ) -> None:
        """One batch of samples as they arrive (columnar, sensor time)."""
        t = np.asarray(t_s, dtype=np.float64)
        if t.size:
            self._t_s = max(self._t_s, float(t[-1]))
        self.run.log_samples("raw", t, sample_index, accel_g, "g")
        if calibrated_g is not None:
            self.run.log_samples("calibrated", t, sample_index, calibrated_g, "g")
        if temp_degC is not None:
            self.run.log_temperature(t, temp_degC)
        if self._integrator is not None and t.size:
            step = self._integrator.push(t, calibrated_g if calibrated_g is not None else accel_g)
            self.run.log_series(
                f"{TRACKS}/live", t, step.disp_m, [f"live {a} (m)" for a in AXES], role="track"
            )

    # RecorderUI + on_batch --------------------------------------------------------------------------
    def prompt(self, index: int, total: int, pose) -> None:
        self.pose_prompt(pose.name, pose.up_sensor, index=index, total=total)

    def waiting(self, moving: bool, still_for_s: float) -> None:
        self.stillness(self._t_s, not moving, still_for_s)

    def holding(self, pose, done_s: float) -> None:
        pass

    def finished_pose(self, label: PoseLabel) -> None:
        self.run.log_poses([label])

    def on_batch(self, batch, accel_g: np.ndarray) -> None:
        """Recorder callback: batch has t_ns (int64 ns), first_index, optional temp_counts."""
        try:
            t = np.asarray(batch.t_ns, dtype=np.int64) / 1e9
            idx = int(batch.first_index) + np.arange(t.shape[0])
            temp = getattr(batch, "temp_counts", None)
            if temp is not None:
                from accellog.core.units import temp_counts_to_degC

                temp = temp_counts_to_degC(np.asarray(temp, dtype=np.float64))
        except Exception as exc:
            self.run._fail(f"live view: bad batch: {exc}")
            return
        self.log_batch(t, idx, accel_g, temp_degC=temp)

    def close(self) -> None:
        self.run.close()
        msg = self.run.report()
        if msg:
            with contextlib.suppress(Exception):
                self.run._on_failure(msg)


class _TeeUI:
    """RecorderUI calling the operator's UI first, then the (guarded) live view."""

    def __init__(self, ui, live: LiveView) -> None:
        self.ui, self.live = ui, live

    def _both(self, name: str, *args) -> None:
        if self.ui is not None:
            getattr(self.ui, name)(*args)
        try:
            getattr(self.live, name)(*args)
        except Exception as exc:  # the live view never stops the recorder
            self.live.run._fail(f"live view: {name}: {exc}")

    def prompt(self, index: int, total: int, pose) -> None:
        self._both("prompt", index, total, pose)

    def waiting(self, moving: bool, still_for_s: float) -> None:
        self._both("waiting", moving, still_for_s)

    def holding(self, pose, done_s: float) -> None:
        self._both("holding", pose, done_s)

    def finished_pose(self, label: PoseLabel) -> None:
        self._both("finished_pose", label)


def wait_for_port(host: str, port: int, timeout_s: float = 20.0) -> bool:
    """True once a TCP connection to host:port succeeds within timeout_s (s; 0: one attempt)."""
    end = time.monotonic() + timeout_s
    while True:
        try:
            with socket.create_connection((host, port), timeout=0.5):
                return True
        except OSError:
            if time.monotonic() >= end:
                return False
            time.sleep(0.1)
