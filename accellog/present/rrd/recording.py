"""``RunRecording``: pipeline arrays in, a Rerun recording laid out for the user's question.

It knows nothing about files of accellog: the stages hand it numpy arrays (samples, poses, residuals,
tracks, documents) and it writes them columnar (``send_columns``, one call per stream and batch, never
per sample) on the main timeline ``sensor_time`` (duration, s since session start) plus ``sample``
(sequence, device sample index) for raw streams. Entity paths in ``entities``.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import urllib.parse
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from accellog.core.errors import InputError
from accellog.core.session import Event, PoseLabel
from accellog.present.rrd.entities import (
    _EVENT_LEVEL,
    _TRACK_COLORS,
    AXES,
    AXIS_COLORS,
    DOCS,
    EVENTS,
    EVENTS_LOST,
    LADDER,
    LADDER_METRICS,
    MAIN_TIMELINE,
    POSE_TIMELINE,
    POSES_ACTIVE,
    POSES_LOG,
    RESIDUALS,
    SAMPLE_TIMELINE,
    SPAWN_PORT,
    TEMPERATURE,
    TRACK_3D_MAX_POINTS,
    TRACKS,
    WORLD_TRACKS,
    _as_2d,
    slug,
    slug_path,
)
from accellog.present.rrd.envelope import (
    FULL_RATE_MAX_SAMPLES,
    EnvelopeBuilder,
    bucket_width_s,
    minmax_envelope,
    track_keep,
)
from accellog.present.rrd.layout import build_blueprint, live_blueprint
from accellog.present.rrd.ranges import with_time_ranges
from accellog.present.rrd.sinks import SinkWatch, parse_sink, spawn_viewer
from accellog.store.atomic import AtomicOutput

if TYPE_CHECKING:
    from accellog.calibrate.ladder import LadderRow


class RunRecording:
    """A Rerun recording of one pipeline run (see the module docstring for the entity layout).

    sink: 'save:PATH' | 'spawn' | 'connect' | 'connect:URL'. blueprint: 'auto' (a layout built on
    close from what was logged; live sinks get the full standard layout up front), None (no
    blueprint), or an ``rrb.Blueprint``. guard: catch and count logging failures instead of raising
    (default: True for live sinks, False for files). on_failure: called once with a one-line
    message at the first failure (default: print to stderr). full_rate: log long series at the full
    rate instead of display envelopes (``present.rrd.envelope``; default: the environment variable
    ACCELLOG_RRD_FULL=1, else envelopes for series longer than FULL_RATE_MAX_SAMPLES).
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
        full_rate: bool | None = None,
    ) -> None:
        import rerun as rr

        if full_rate is None:
            full_rate = os.environ.get("ACCELLOG_RRD_FULL", "").strip().lower() in ("1", "true", "yes")
        self.full_rate = bool(full_rate)
        self._span: tuple[float, float] | None = None  # batched logging: (t0, bucket width) s
        self._builders: dict[str, tuple[EnvelopeBuilder, bool]] = {}  # entity -> (builder, has index)
        self._extents: dict[str, tuple[float, float]] = {}  # entity -> (first, last) sensor_time (s)
        self.kind, self.target = parse_sink(sink)
        self.guard = (self.kind != "save") if guard is None else guard
        self.failures = 0
        self.first_failure: str | None = None
        self.down = False
        self._on_failure = on_failure or (lambda msg: print(f"accellog: warning: {msg}", file=sys.stderr))
        self._blueprint = blueprint
        self._entities: dict[str, str] = {}  # entity path -> role, drives the auto blueprint
        self._closed = False
        self._watch: SinkWatch | None = None
        self._tmp: Path | None = None
        self._final: Path | None = None
        self._out: AtomicOutput | None = None
        self._lock = threading.Lock()
        self._n_tracks = 0
        self._n_poses = 0  # holds logged so far: /poses/active/{k} numbers them across calls
        self.rec = rr.RecordingStream(app_id, recording_id=recording_id, send_properties=False)
        with contextlib.suppress(AttributeError):
            self.rec.set_log_time_enabled(False)  # reproducible files: no wall-clock timeline
        bp = self._initial_blueprint()
        if self.kind == "save":
            self._final = Path(self.target)
            self._out = AtomicOutput(self._final, what="--rrd output")
            self._tmp = self._out.begin()  # checks the path, locks it, reserves a unique temp name
            try:  # the blueprint goes in on close, with each view's time range (present.rrd.ranges)
                self.rec.save(str(self._tmp), default_blueprint=None)
            except BaseException:
                self._out.abort()
                raise
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
            spawn_viewer(port)
            self.rec.connect_grpc(f"rerun+http://{host}:{port}/proxy", default_blueprint=bp)
        else:
            self.rec.connect_grpc(self.target, default_blueprint=bp)
            u = urllib.parse.urlparse(self.target.replace("rerun+", "", 1))
            host, port = u.hostname or "127.0.0.1", u.port or 9876
        self._watch = SinkWatch(host, port, self._sink_down)

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
        decimate: bool = True,
    ) -> None:
        """Columnar scalars (N,k) on sensor_time (and ``sample`` if given); names label the k series.

        decimate: a long series (or any series while ``begin_batches`` is in force) is logged as its
        min/max display envelope unless the recording is ``full_rate`` (see the module docstring)."""
        self._guarded(
            self._log_series, entity, t_s, values, names, sample_index, role, colors, points, step, decimate
        )

    def _log_series(
        self, entity, t_s, values, names, sample_index, role, colors, points, step, decimate=False
    ) -> None:
        import rerun as rr

        t = np.asarray(t_s, dtype=np.float64)
        v = _as_2d(values, t.shape[0], entity)
        if decimate and not self.full_rate:
            t, v, sample_index = self._envelope(entity, t, v, sample_index)
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
        lo, hi = self._extents.get(entity, (np.inf, -np.inf))
        self._extents[entity] = (min(lo, float(np.nanmin(t))), max(hi, float(np.nanmax(t))))
        idx = [rr.TimeColumn(MAIN_TIMELINE, duration=t)]
        if sample_index is not None:
            idx.append(rr.TimeColumn(SAMPLE_TIMELINE, sequence=np.asarray(sample_index, dtype=np.int64)))
        cols = v[:, 0] if v.shape[1] == 1 else v
        self.rec.send_columns(entity, indexes=idx, columns=rr.Scalars.columns(scalars=cols))

    def _envelope(self, entity, t, v, sample_index):
        """(t, v, sample_index) to log: the display envelope's rows, or the input when it is short."""
        if self._span is not None:
            if entity not in self._builders:
                self._builders[entity] = (EnvelopeBuilder(*self._span), sample_index is not None)
            env = self._builders[entity][0].push(t, v, sample_index)
        elif t.shape[0] > FULL_RATE_MAX_SAMPLES:
            env = minmax_envelope(t, v, index=sample_index)
        else:
            return t, v, sample_index
        return env.t_s, env.values, (None if sample_index is None else env.row_index)

    def begin_batches(self, t0_s: float, t1_s: float, n_samples: int) -> None:
        """Series of a session spanning t0_s..t1_s (s, n_samples samples) follow batch by batch: their
        envelopes share buckets of (t1 - t0) / ENVELOPE_BUCKETS s across calls (no envelope when
        n_samples <= FULL_RATE_MAX_SAMPLES). ``end_batches`` (or close) writes the last buckets."""
        self.end_batches()
        if n_samples > FULL_RATE_MAX_SAMPLES:
            self._span = (float(t0_s), bucket_width_s(float(t1_s) - float(t0_s)))

    def end_batches(self) -> None:
        """Write the open bucket of every batched envelope and return to one-shot logging."""
        builders, self._builders, self._span = self._builders, {}, None
        for entity, (eb, has_index) in builders.items():
            env = eb.finish()
            idx = env.row_index if has_index else None
            self._guarded(self._log_series, entity, env.t_s, env.values, [], idx, "", None, False, False)

    def log_static(self, entity: str, archetype: Any, role: str = "static") -> None:
        """Any Rerun archetype logged once (static) at entity; role picks its view in the blueprint."""
        self._guarded(self._log_static, entity, archetype, role)

    def _log_static(self, entity: str, archetype: Any, role: str) -> None:
        self._entities.setdefault(entity, role)
        self.rec.log(entity, archetype, static=True)

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
        t = np.asarray(t_s, dtype=np.float64)
        keep = slice(None)
        if not self.full_rate and d.shape[0] > FULL_RATE_MAX_SAMPLES:  # smooth: every k-th + the last
            keep = track_keep(d.shape[0])
        self._log_series(
            f"{TRACKS}/{slug_path(label)}",
            t[keep],
            d[keep],
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

    def log_ladder(
        self,
        rows: Sequence[LadderRow],
        *,
        t_s: np.ndarray | None = None,
        driver: np.ndarray | None = None,
        driver_name: str = "",
        residual_steps: Iterable[int] = (),
    ) -> None:
        """The model ladder: a table document, per metric (LADDER_METRICS) one bar per step with
        log10 of chi2/dof, held-out RMS (mg) and static-test drift (m), named by the step's model;
        for the steps in residual_steps their calibration residuals (mg) at t_s (s) next to the
        driver (e.g. temperature, degC) that the next effect explains."""
        self._guarded(self._log_ladder, list(rows), t_s, driver, driver_name, set(residual_steps))

    def _log_ladder(self, rows, t_s, driver, driver_name, residual_steps) -> None:
        import rerun as rr

        if not rows:
            return
        self._log_document("ladder", _ladder_markdown(rows))
        for i, r in enumerate(rows):
            held = None if r.heldout_rms_g is None else r.heldout_rms_g * 1000.0
            for metric, v in zip(LADDER_METRICS, (r.chi2_dof, held, r.drift_m), strict=True):
                if v is None or not np.isfinite(v) or v <= 0:
                    continue
                ent = f"{LADDER}/{metric}/{i:02d}_{slug(r.model)}"
                self._entities[ent] = "ladder_bar"
                color = _TRACK_COLORS[i % len(_TRACK_COLORS)]
                self.rec.log(ent, rr.BarChart([np.log10(v)], abscissa=[float(i)], color=color), static=True)
        self.rec.log(
            LADDER,
            rr.AnyValues(step=[r.model for r in rows], added=["+".join(r.added) for r in rows]),
            static=True,
        )
        if t_s is None:
            return
        t = np.asarray(t_s, dtype=np.float64)
        for i in sorted(residual_steps):
            r = rows[i]
            if r.residual_g is None:
                continue
            base = f"{LADDER}/steps/{i:02d}"
            res_mg = np.asarray(r.residual_g, dtype=np.float64).reshape(-1, 3) * 1000.0
            names = [f"{i} {r.model} res {a} (mg)" for a in AXES]
            self._log_series(
                f"{base}/residual_mg", t, res_mg, names, None, "ladder_step", AXIS_COLORS, True, False
            )
            if driver is not None:
                self._log_series(
                    f"{base}/driver",
                    t,
                    np.asarray(driver, dtype=np.float64),
                    [f"driver {driver_name}"],
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

    @property
    def extents(self) -> dict[str, tuple[float, float]]:
        """Entity paths of the series logged on sensor_time -> (first, last) time (s)."""
        return dict(self._extents)

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
            self.end_batches()
            if self.kind == "save" and self._blueprint is not None:
                bp = build_blueprint(self._entities) if isinstance(self._blueprint, str) else self._blueprint
                bp = with_time_ranges(bp, self._extents)
                self.rec.send_blueprint(bp, make_active=True, make_default=True)
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
        if self._out is not None:
            self._out.commit()

    def abort(self) -> None:
        """Stop without producing a file (a temporary file is removed)."""
        if self._watch is not None:
            self._watch.stop()
        if not self._closed:
            self._closed = True
            with contextlib.suppress(Exception):
                self.rec.disconnect()
        if self._out is not None:
            self._out.abort()

    def __enter__(self) -> RunRecording:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


# -- blueprints --------------------------------------------------------------------------------------


def _ladder_markdown(rows: Sequence[LadderRow]) -> str:
    """The ladder as a markdown table (chi2/dof, held-out RMS in mg, static-test drift in m)."""

    def f(v: float | None, scale: float = 1.0) -> str:
        return "-" if v is None else f"{v * scale:.3g}"

    md = [
        "### Model ladder\n",
        "| # | model | added | chi2/dof | held-out RMS (mg) | drift (m) at (s) |",
        "|---|---|---|---|---|---|",
    ]
    for i, r in enumerate(rows):
        at = "" if r.drift_at_s is None else f" at {r.drift_at_s:g}"
        md.append(
            f"| {i} | {r.model} | {'+'.join(r.added)} | {f(r.chi2_dof)} | {f(r.heldout_rms_g, 1000.0)} "
            f"| {f(r.drift_m)}{at} |"
        )
    return "\n".join(md) + "\n"
