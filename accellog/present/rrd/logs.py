"""What a run logs beyond plain series: hold windows, events, residuals per pose, displacement
tracks (time series and 3D), markdown documents and the model ladder.

``PipelineLogs`` is a mixin of ``RunRecording`` (present/rrd/recording.py): its methods write through
the recording's guarded, columnar ``_log_series`` and its Rerun stream ``rec``; entity paths in
``entities``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from accellog.core.errors import InputError
from accellog.core.session import Event, PoseLabel
from accellog.present.rrd.bars2d import log_bar_groups
from accellog.present.rrd.entities import (
    AXES,
    AXIS_COLORS,
    CHARTS,
    DOCS,
    EVENT_LEVEL,
    EVENTS,
    EVENTS_LOST,
    LADDER,
    LADDER_METRICS,
    MAIN_TIMELINE,
    POSE_TIMELINE,
    POSES_ACTIVE,
    POSES_LOG,
    RESIDUALS,
    TRACK_COLORS,
    TRACKS,
    WORLD_TRACKS,
    slug,
    slug_path,
    track_color,
)

if TYPE_CHECKING:
    from accellog.calibrate.diagnosis.ladder import LadderRow


class PipelineLogs:
    """Logging methods for pipeline results (mixed into RunRecording, which provides ``rec``,
    ``_guarded``, ``_log_series``, ``_entities``, ``full_rate``, ``_n_tracks``, ``_n_poses`` and
    ``_finals3d``: 3D final point entity -> (position m, label), decluttered on close). Tracks come
    reduced by ``SeriesLogs.log_track`` / ``log_track_3d`` (series.py)."""

    rec: Any
    full_rate: bool
    _entities: dict[str, str]
    _n_tracks: int
    _n_poses: int
    _finals3d: dict[str, tuple[np.ndarray, str]]

    if TYPE_CHECKING:  # RunRecording's (offload.py, series.py)

        def _guarded(self, fn: Callable[..., Any], *args: Any, **kw: Any) -> Any: ...

        def _log_series(
            self, entity, t_s, values, names, sample_index, role, colors, points, step, decimate=False
        ) -> None: ...

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

    def log_curve(self, entity: str, timeline: str, x: np.ndarray, values: np.ndarray, names: Sequence[str],
                  role: str) -> None:  # fmt: skip
        """Lines values (n, k) against a sequence timeline of integers x (n,) (e.g. a temperature in
        mdegC: a plot whose x axis is not time; the view shows it with that timeline selected)."""
        self._guarded(
            self._log_curve, entity, timeline, np.asarray(x), np.asarray(values, float), list(names), role
        )

    def _log_curve(self, entity, timeline, x, values, names, role) -> None:
        import rerun as rr

        self._entities[entity] = role
        self.rec.log(entity, rr.SeriesLines(names=names), static=True)
        self.rec.send_columns(entity, indexes=[rr.TimeColumn(timeline, sequence=x.astype(np.int64))],
                              columns=rr.Scalars.columns(scalars=values.reshape(len(x), -1)))  # fmt: skip

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
        levels = [EVENT_LEVEL.get(e.kind, "INFO") for e in events]
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
        log_bar_groups(self, f"{CHARTS}/{base}", pose_names, list(AXES), AXIS_COLORS, res_mg, unit="mg")
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

    def _write_track(self, label: str, t: np.ndarray, d: np.ndarray, d_strip: np.ndarray) -> None:
        """A displacement track as ``SeriesLogs.log_track`` has reduced it: the time series (t (N,) s,
        d (N,3) m) and the 3D strip (d_strip (M,3) m, its last row the final displacement)."""
        color = track_color(self._n_tracks)
        if f"{TRACKS}/{slug_path(label)}" not in self._entities:
            self._n_tracks += 1
        name = str(label).rsplit("/", 1)[-1]
        self._log_series(
            f"{TRACKS}/{slug_path(label)}",
            t,
            d,
            [f"{name} {a} (m)" for a in AXES],
            None,
            "track",
            AXIS_COLORS,
            False,
            False,
        )
        if d_strip.shape[0]:
            self._write_track_3d(label, d_strip, color)

    def _write_track_3d(self, label: str, d_strip: np.ndarray, color: tuple[int, int, int] | None) -> None:
        """The static 3D line strip (SeriesLogs.log_track_3d) and its final point (the last row)."""
        import rerun as rr

        color = color or TRACK_COLORS[0]
        ent = f"{WORLD_TRACKS}/{slug_path(label)}"
        self._entities[ent] = "track3d"
        final = d_strip[-1]
        label = str(label).rsplit("/", 1)[-1]
        # the strip's label stays in the data but is not drawn: the final point carries the name
        self.rec.log(
            ent, rr.LineStrips3D([d_strip], colors=[color], labels=[label], show_labels=False), static=True
        )
        shown = np.where(np.abs(final) < 1e-9, 0.0, final)  # no '-4.5e-15' for an exact zero
        text = f"{label}: ({shown[0]:+.3g}, {shown[1]:+.3g}, {shown[2]:+.3g}) m"
        self.rec.log(
            f"{ent}/final",
            rr.Points3D(
                [final],
                colors=[color],
                radii=[-6.0],  # negative radius = screen-space points (ui points)
                labels=[text],
            ),
            static=True,
        )
        self._finals3d[f"{ent}/final"] = (final, text)

    def _declutter_3d_labels(self, near: float = 0.06) -> None:
        """Final points of one 3D group (``/world/tracks/<group>/...``) closer than near x the group's
        extent share one label (their labels one per line, on the farthest point from the origin);
        the others hide theirs. Points and colours are left as logged."""
        import rerun as rr

        groups: dict[str, list[str]] = {}
        for ent in self._finals3d:
            groups.setdefault(ent.rsplit("/", 2)[0], []).append(ent)
        for ents in groups.values():
            pts = np.array([self._finals3d[e][0] for e in ents], dtype=np.float64)
            scale = max(float(np.ptp(np.vstack([pts, np.zeros(3)]), axis=0).max()), 1e-9)
            heads: list[list[int]] = []
            for k in np.argsort(-np.linalg.norm(pts, axis=1), kind="stable"):
                for h in heads:
                    if np.linalg.norm(pts[k] - pts[h[0]]) < near * scale:
                        h.append(int(k))
                        break
                else:
                    heads.append([int(k)])
            for h in (h for h in heads if len(h) > 1):
                text = "\n".join(self._finals3d[ents[k]][1] for k in h)
                self.rec.log(ents[h[0]], rr.Points3D.from_fields(labels=[text]), static=True)
                for k in h[1:]:
                    self.rec.log(ents[k], rr.Points3D.from_fields(show_labels=False), static=True)

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
                color = step_color(i)
                self.rec.log(ent, rr.BarChart([np.log10(v)], abscissa=[float(i)], color=color), static=True)
        self.rec.log(
            LADDER,
            rr.AnyValues(step=[r.model for r in rows], added=["+".join(r.added) for r in rows]),
            static=True,
        )
        values = np.array([_ladder_values(r) for r in rows], dtype=np.float64).T
        measured = [k for k, v in enumerate(values) if np.any(np.isfinite(v) & (v > 0))]  # no empty group
        log_bar_groups(
            self,
            f"{CHARTS}/{LADDER}",
            [list(LADDER_BAR_GROUPS.values())[k] for k in measured],
            ladder_step_names(rows),
            [step_color(i) for i in range(len(rows))],
            values[measured],
            log10=True,
            width=720.0,
        )
        if t_s is None:
            return
        t = np.asarray(t_s, dtype=np.float64)
        short = ladder_step_names(rows)
        for i in sorted(residual_steps):
            r = rows[i]
            if r.residual_g is None:
                continue
            res_mg = np.asarray(r.residual_g, dtype=np.float64).reshape(-1, 3) * 1000.0
            names = [f"{short[i]} {a} (mg)" for a in AXES]
            colors = axis_shades(step_color(i))  # the step's colour (as its bars), a shade per axis
            ent = f"{LADDER}/steps/{i:02d}/residual_mg"
            self._log_series(ent, t, res_mg, names, None, "ladder_step", colors, True, False)
        if driver is not None:  # once, on its own axis (degC and mg do not share one)
            d = np.asarray(driver, dtype=np.float64)
            self._log_series(
                LADDER_DRIVER, t, d, [driver_name], None, "ladder_driver", [(120, 120, 120)], False, False
            )


LADDER_DRIVER = f"{LADDER}/driver"
"""What the ladder's residuals are plotted against (e.g. temperature, degC), once."""
LADDER_BAR_GROUPS = {
    "log10_chi2_dof": "χ²/dof (fit)",
    "log10_heldout_rms_mg": "held-out RMS (mg)",
    "log10_drift_m": "static-test drift (m)",
}
"""Group names of the ladder's 2D bar chart (one group per metric of LADDER_METRICS)."""


STEP_COLORS = [c for c in TRACK_COLORS if len(set(c)) > 1] + [
    (240, 220, 80),
    (110, 220, 200),
    (250, 150, 190),
]
"""Colours of the ladder's steps: never grey (grey is a model the workbench did not keep)."""


def step_color(i: int) -> tuple[int, int, int]:
    """Colour of ladder step i (its bars, its residual series and its calibration in every panel)."""
    return STEP_COLORS[i % len(STEP_COLORS)]


def axis_shades(rgb: tuple[int, int, int]) -> list[tuple[int, int, int]]:
    """x, y, z shades of one colour (dark, as is, light): a model's three axes in one plot."""
    c = np.asarray(rgb, dtype=np.float64)
    return [_rgb(s) for s in (0.6 * c, c, c + 0.5 * (255.0 - c))]


def _rgb(c: np.ndarray) -> tuple[int, int, int]:
    r, g, b = (int(v) for v in c)
    return r, g, b


def ladder_step_names(rows: Sequence[LadderRow]) -> list[str]:
    """Short names of the ladder's steps: 'k model' for a base model, 'k +effect' for a step that
    adds an effect to the previous one ('k +a+b' for two added together)."""
    out, before = [], []
    for i, r in enumerate(rows):
        new = [e for e in r.added if e not in before] or r.added[-1:]
        out.append(f"{i} +{'+'.join(new)}" if r.added else f"{i} {r.model}")
        before = list(r.added)
    return out


def _ladder_values(r: LadderRow) -> list[float]:
    """chi2/dof, held-out RMS (mg), drift (m) of a ladder step (NaN where not measured)."""
    held = None if r.heldout_rms_g is None else r.heldout_rms_g * 1000.0
    return [np.nan if v is None else float(v) for v in (r.chi2_dof, held, r.drift_m)]


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
