"""``RunRecording``: pipeline arrays in, a Rerun recording laid out for the user's question.

It knows nothing about files of accellog: the stages hand it numpy arrays (samples, poses, residuals,
tracks, documents) and it writes them columnar (``send_columns``, one call per stream and batch, never
per sample; a file sink gathers a series' small batches, such as envelope rows, into calls of up to
``COALESCE_ROWS`` rows) on the main timeline ``sensor_time`` (duration, s since session start) plus
``sample`` (sequence, device sample index) for raw streams. Entity paths in ``entities``.

This module holds the sink, the guard against live-view failures, the rows of generic series as they
go into the file and closing with the blueprint (each view's time range: ``ranges``); series are
checked and reduced to display envelopes (``envelope``) by the ``SeriesLogs`` mixin (``series``),
holds, events, residuals, tracks, documents and the ladder are logged by the ``PipelineLogs`` mixin
(``logs``).
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import urllib.parse
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from accellog.core.errors import InputError
from accellog.present.rrd.entities import (
    MAIN_TIMELINE,
    SAMPLE_TIMELINE,
    SPAWN_PORT,
)
from accellog.present.rrd.layout import build_blueprint, live_blueprint
from accellog.present.rrd.logs import PipelineLogs
from accellog.present.rrd.ranges import with_time_ranges
from accellog.present.rrd.sdk import rerun_sdk
from accellog.present.rrd.series import SeriesLogs
from accellog.present.rrd.sinks import SinkWatch, parse_sink, spawn_viewer
from accellog.store.atomic import AtomicOutput

COALESCE_ROWS = 16_384
"""A file sink sends a series' batches of fewer rows than this gathered, up to this many rows per
``send_columns`` call (a call costs ~0.15 ms; a replay logs ~130 envelope rows per series and batch).
Live sinks get every batch as it comes."""


RRD_FOOTER = b"RRF2FOOT"
"""The magic of the footer rerun's file sink writes last (rerun 0.41): a file without it was cut."""


def check_finished(tmp: Path | None, final: Path | None) -> None:
    """InputError when the file rerun's sink wrote does not end with its footer: the sink's writer
    thread failed (a full disk, an I/O error; rerun only logs it), so the file is not committed."""
    if tmp is None:
        return
    try:
        with open(tmp, "rb") as f:
            f.seek(max(0, os.fstat(f.fileno()).st_size - 64))
            tail = f.read()
    except OSError as exc:
        raise InputError(f"cannot read the recording back: {exc.strerror or exc}", where=str(final)) from None
    if RRD_FOOTER not in tail:
        raise InputError(
            f"the recording could not be written completely{_space(final)}; nothing was kept",
            where=str(final),
        )


def _space(path: Path | None) -> str:
    """'; its file system is full' when the folder of path has less than 1 MiB free, else ''."""
    try:
        st = os.statvfs(Path(path).parent if path is not None else ".")
    except OSError:
        return ""
    return "; its file system is full" if st.f_bavail * st.f_frsize < 1024**2 else ""


class RunRecording(SeriesLogs, PipelineLogs):
    """A Rerun recording of one pipeline run (see the module docstring for the entity layout).

    sink: 'save:PATH' | 'spawn' | 'connect' | 'connect:URL'. blueprint: 'auto' (a layout built on
    close from what was logged; live sinks get the full standard layout up front), None (no
    blueprint), or an ``rrb.Blueprint``. guard: catch and count logging failures instead of raising
    (default: True for live sinks, False for files). on_failure: called once with a one-line
    message at the first failure (default: print to stderr). full_rate: log long series at the full
    rate instead of display envelopes (``present.rrd.envelope``; default: ``DEFAULT_FULL_RATE``,
    which the CLI sets from ACCELLOG_RRD_FULL=1; else envelopes for series longer than
    FULL_RATE_MAX_SAMPLES). output (file sinks): an ``AtomicOutput`` the caller has begun (the path
    checked and locked, its temporary file reserved): the recording is written to its temporary file
    and committed or aborted through it (``present.rrd.offload``: the parent process owns the file,
    a child writes it); default: one of its own for the sink's path.
    """

    DEFAULT_FULL_RATE = False
    """full_rate when a caller does not say; configuration, set by the command line only."""

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
        output: AtomicOutput | None = None,
    ) -> None:
        rr = rerun_sdk()
        self.full_rate = bool(type(self).DEFAULT_FULL_RATE if full_rate is None else full_rate)
        self._init_series()  # envelopes and batches (series.py)
        self._extents: dict[str, tuple[float, float]] = {}  # entity -> (first, last) sensor_time (s)
        self._pending: dict[str, tuple[int, list]] = {}  # entity -> (rows, [(t, v, index)]) to send
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
        self._finals3d: dict[str, tuple[np.ndarray, str]] = {}  # 3D final points (logs.py)
        self.rec = rr.RecordingStream(app_id, recording_id=recording_id, send_properties=False)
        with contextlib.suppress(AttributeError):
            self.rec.set_log_time_enabled(False)  # reproducible files: no wall-clock timeline
        bp = self._initial_blueprint()
        if self.kind == "save":
            self._final = Path(self.target)
            if output is None:
                output = AtomicOutput(self._final, what="--rrd output")
                output.begin()  # checks the path, locks it, reserves a unique temp name
            self._out, self._tmp = output, output.tmp
            try:  # the blueprint goes in on close, with each view's time range (present.rrd.ranges)
                self.rec.save(str(self._tmp), default_blueprint=None)
            except BaseException as exc:
                self._out.abort()
                if isinstance(exc, RuntimeError):  # rerun's file sink: a full disk, an I/O error
                    raise InputError(
                        f"cannot write the recording: {exc}{_space(self._final)}", where=str(self._final)
                    ) from None
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
    def _write_series(self, entity, t, v, names, sample_index, role, colors, points, step) -> None:
        """Rows as they go into the file (``SeriesLogs._log_series`` has checked and reduced them): the
        series' style on first use, its extent, and the rows sent or gathered (module docstring)."""
        import rerun as rr

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
        idx = None if sample_index is None else np.asarray(sample_index, dtype=np.int64)
        if self.kind != "save" or t.shape[0] >= COALESCE_ROWS:
            self._send_pending(entity)
            self._send(entity, t, v, idx)
            return
        rows, parts = self._pending.get(entity, (0, []))
        if parts and (parts[0][2] is None) != (idx is None):  # the sample timeline comes or goes
            self._send_pending(entity)
            rows, parts = 0, []
        parts.append((t.copy(), v.copy(), None if idx is None else idx.copy()))  # the caller's may change
        self._pending[entity] = (rows + t.shape[0], parts)
        if rows + t.shape[0] >= COALESCE_ROWS:
            self._send_pending(entity)

    def _end_rows(self) -> None:
        self._guarded(self._send_pending)

    def _send_pending(self, entity: str | None = None) -> None:
        """Send the gathered rows of entity (None: of every series)."""
        for e in list(self._pending) if entity is None else [entity]:
            _, parts = self._pending.pop(e, (0, []))
            if parts:  # every part has the sample index or none has
                ts, vs, idxs = zip(*parts, strict=True)
                idx = None if idxs[0] is None else np.concatenate(idxs)
                self._send(e, np.concatenate(ts), np.concatenate(vs), idx)

    def _send(self, entity: str, t: np.ndarray, v: np.ndarray, idx: np.ndarray | None) -> None:
        import rerun as rr

        index = [rr.TimeColumn(MAIN_TIMELINE, duration=t)]
        if idx is not None:
            index.append(rr.TimeColumn(SAMPLE_TIMELINE, sequence=idx))
        cols = v[:, 0] if v.shape[1] == 1 else v
        self.rec.send_columns(entity, indexes=index, columns=rr.Scalars.columns(scalars=cols))

    def log_static(self, entity: str, archetype: Any, role: str = "static") -> None:
        """Any Rerun archetype logged once (static) at entity; role picks its view in the blueprint."""
        self._guarded(self._log_static, entity, archetype, role)

    def _log_static(self, entity: str, archetype: Any, role: str) -> None:
        self._entities.setdefault(entity, role)
        self.rec.log(entity, archetype, static=True)

    # -- pipeline data -------------------------------------------------------------------------------
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
            self._guarded(self._declutter_3d_labels)
            if self.kind == "save" and self._blueprint is not None:
                ends = [end for end, _ in self._finals3d.values()]
                bp = (
                    build_blueprint(self._entities, ends)
                    if isinstance(self._blueprint, str)
                    else self._blueprint
                )
                bp = with_time_ranges(bp, self._extents)
                # active: a viewer reading the file has built a layout from the data by now
                self.rec.send_blueprint(bp, make_active=True, make_default=True)
            if self.kind == "save":
                self._flush_file()
                self.rec.disconnect()
                check_finished(self._tmp, self._final)
            elif self.down:  # dropping an unreachable gRPC sink waits up to 5 s: on a thread of its
                # own, not in the caller nor wherever the garbage collector happens to drop it later
                threading.Thread(target=self._disconnect_quietly, daemon=True).start()
            else:
                self._guarded(self.rec.flush, timeout_sec=2.0)
                self._guarded(self.rec.disconnect)
        except BaseException as exc:
            self.abort()  # no half-written file left behind
            if isinstance(exc, RuntimeError) and self.kind == "save":  # rerun's file sink failed
                raise InputError(
                    f"cannot write the recording: {exc}{_space(self._final)}", where=str(self._final)
                ) from None
            raise
        finally:
            self._closed = True
        if self._out is not None:
            self._out.commit()

    DISCONNECT_WAIT_S = 5.0
    """How long abort waits for rerun to let go of a sink."""
    FLUSH_STEP_S = 2.0
    """A file sink's flush is waited for in steps of this many seconds while the file grows."""

    def _flush_file(self) -> None:
        """Flush the file sink, waiting while the file grows: rerun's flush (timeout infinite) never
        returns when its writer thread died meanwhile (a full disk), so it is waited for in steps and
        given up when a step wrote nothing (RuntimeError, turned into one line by close)."""
        size = -1
        while True:
            try:
                self.rec.flush(timeout_sec=self.FLUSH_STEP_S)
                return
            except RuntimeError:  # a timeout, or the sink failed
                now = self._tmp.stat().st_size if self._tmp is not None and self._tmp.exists() else -1
                if now == size:
                    raise
                size = now

    def _disconnect_quietly(self) -> None:
        with contextlib.suppress(Exception):
            self.rec.disconnect()

    def abort(self) -> None:
        """Stop without producing a file (a temporary file is removed)."""
        if self._watch is not None:
            self._watch.stop()
        if not self._closed:
            self._closed = True
            # rerun's disconnect flushes the sink without a timeout and never returns when its file
            # writer died (a full disk): waited for DISCONNECT_WAIT_S on a thread of its own, and if it
            # hangs, rerun's exit handler (the same flush) is dropped so that the process can end
            t = threading.Thread(target=self._disconnect_quietly, name="accellog-rrd-abort", daemon=True)
            t.start()
            t.join(self.DISCONNECT_WAIT_S)
            if t.is_alive():
                with contextlib.suppress(Exception):
                    rerun_sdk().unregister_shutdown()
        if self._out is not None:
            self._out.abort()

    def __enter__(self) -> RunRecording:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
