"""What a run logs beyond plain series: hold windows, events, residuals per pose, displacement
tracks (time series and 3D), markdown documents and the model ladder.

``PipelineLogs`` is a mixin of ``RunRecording`` (present/rrd/recording.py): its methods write through
the recording's guarded, columnar ``_log_series`` and its Rerun stream ``rec``; entity paths in
``entities``.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
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
    TRACK_3D_MAX_POINTS,
    TRACKS,
    WORLD_TRACKS,
    slug,
    slug_path,
)
from accellog.present.rrd.envelope import FULL_RATE_MAX_SAMPLES, track_keep

if TYPE_CHECKING:
    from accellog.calibrate.ladder import LadderRow


class PipelineLogs:
    """Logging methods for pipeline results (mixed into RunRecording, which provides ``rec``,
    ``_guarded``, ``_log_series``, ``_entities``, ``full_rate``, ``_n_tracks`` and ``_n_poses``)."""

    rec: Any
    full_rate: bool
    _entities: dict[str, str]
    _n_tracks: int
    _n_poses: int

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
