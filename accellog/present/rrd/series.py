"""``SeriesLogs``: the part of a recording that needs no Rerun: series checked and reduced to their
display envelopes, batch by batch or at once.

A mixin of ``RunRecording`` (present/rrd/recording.py) and of ``OffloadedRecording``
(present/rrd/offload.py): both check a series (``as_2d``), reduce it to the rows the file gets
(``present.rrd.envelope``: min/max envelopes of long series, carried across ``begin_batches`` ...
``end_batches``) and hand the rows to ``_write_series``, which writes them (``RunRecording``) or sends
them to the process that writes them (``OffloadedRecording``): the rows of a file are the same
either way, and only a few kB per batch cross to a writer process instead of every sample (1 h at
1 kHz: ``replay --rrd`` ~2 MB instead of ~320 MB, ``evaluate``/``drift --rrd`` 2 MB instead of
231 MB; sending the samples cost the replay's parent 0.5-0.7 s, building the envelopes here
0.13-0.2 s).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from accellog.core.timeseries import even_indices
from accellog.present.rrd.entities import AXES, AXIS_COLORS, TEMPERATURE, TRACK_3D_MAX_POINTS, as_2d, slug
from accellog.present.rrd.envelope import (
    FULL_RATE_MAX_SAMPLES,
    EnvelopeBuilder,
    bucket_width_s,
    minmax_envelope,
    track_keep,
)


class SeriesLogs:
    """Series logging up to the rows (mixed into a recording, which provides ``full_rate``,
    ``_guarded(fn, *args)`` (run fn unless closed; a guarded recording counts its failures),
    ``_write_series`` (the rows of one series into the file), ``_end_rows`` (every gathered row
    into the file) and ``_write_track`` / ``_write_track_3d`` (a reduced displacement track, logs.py))."""

    full_rate: bool
    _guarded: Callable[..., Any]
    _write_series: Callable[..., None]
    _end_rows: Callable[[], None]
    _write_track: Callable[..., None]
    _write_track_3d: Callable[..., None]

    def _init_series(self) -> None:
        self._span: tuple[float, float] | None = None  # batched logging: (t0, bucket width) s
        self._builders: dict[str, tuple[EnvelopeBuilder, bool]] = {}  # entity -> (builder, has index)
        self._edges: tuple | None = None  # (t, (t[0], t[-1]), starts(t)) of the batch's first series

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
        t = np.asarray(t_s, dtype=np.float64)
        v = as_2d(values, t.shape[0], entity)
        if decimate and not self.full_rate:
            t, v, sample_index = self._envelope(entity, t, v, sample_index)
        self._write_series(entity, t, v, names, sample_index, role, colors, points, step)

    def _envelope(self, entity, t, v, sample_index):
        """(t, v, sample_index) to log: the display envelope's rows, or the input when it is short."""
        if self._span is not None:
            if entity not in self._builders:
                self._builders[entity] = (EnvelopeBuilder(*self._span), sample_index is not None)
            eb = self._builders[entity][0]
            edges = None
            if t.shape[0]:  # the batch's other series (the same t) share its buckets
                e, ends = self._edges, (t[0], t[-1])
                if e is None or e[0] is not t or e[1] != ends:
                    e = self._edges = (t, ends, eb.starts(t))
                edges = e[2]
            env = eb.push(t, v, sample_index, edges)
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

    def begin_stream(self, width_s: float, t0_s: float = 0.0) -> None:
        """Series of an open-ended stream (a live recording) follow batch by batch: their envelopes
        use buckets of width_s s from t0_s on. ``end_batches`` (or close) writes the last buckets."""
        self.end_batches()
        self._span = (float(t0_s), float(width_s))

    def end_batches(self) -> None:
        """Write the open bucket of every batched envelope (and every gathered row: module docstring
        of present.rrd.recording) and return to one-shot logging."""
        builders, self._builders, self._span, self._edges = self._builders, {}, None, None
        for entity, (eb, has_index) in builders.items():
            env = eb.finish()
            idx = env.row_index if has_index else None
            self._guarded(self._log_series, entity, env.t_s, env.values, [], idx, "", None, False, False)
        self._end_rows()

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

    def log_temperature(self, t_s: np.ndarray, temp_degC: np.ndarray) -> None:
        """Die temperature (degC) on sensor_time."""
        self.log_series(TEMPERATURE, t_s, temp_degC, ["die temperature (degC)"], role="temperature")

    def log_track(self, label: str, t_s: np.ndarray, disp_m: np.ndarray) -> None:
        """Displacement track (N,3) in m: time series ``/tracks/{label}`` and a 3D line strip
        ``/world/tracks/{label}`` with its final point (labelled with the final displacement)."""
        self._guarded(self._log_track, label, t_s, disp_m)

    def _log_track(self, label: str, t_s: np.ndarray, disp_m: np.ndarray) -> None:
        d = np.asarray(disp_m, dtype=np.float64).reshape(-1, 3)
        t = np.asarray(t_s, dtype=np.float64)
        keep: slice | np.ndarray = slice(None)
        if not self.full_rate and d.shape[0] > FULL_RATE_MAX_SAMPLES:  # smooth: every k-th + the last
            keep = track_keep(d.shape[0])
        self._write_track(label, t[keep], d[keep], strip_3d(d))

    def log_track_3d(
        self, label: str, disp_m: np.ndarray, *, color: tuple[int, int, int] | None = None
    ) -> None:
        """Static 3D line strip of a whole track (m; decimated, last point kept) + its final point."""
        self._guarded(self._log_track_3d, label, disp_m, color)

    def _log_track_3d(self, label: str, disp_m: np.ndarray, color: tuple[int, int, int] | None) -> None:
        d = np.asarray(disp_m, dtype=np.float64).reshape(-1, 3)
        self._write_track_3d(label, strip_3d(d), color)


def strip_3d(d: np.ndarray) -> np.ndarray:
    """The points of a track (N,3) drawn as its 3D line strip: at most TRACK_3D_MAX_POINTS evenly
    spaced, the last one (the final displacement) always."""
    n = d.shape[0]
    if n <= TRACK_3D_MAX_POINTS:
        return d
    return d[even_indices(n, TRACK_3D_MAX_POINTS)]
