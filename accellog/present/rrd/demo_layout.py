"""The demo's saved layout: one tab per chapter of the story, each view framed on what it shows.

Views of different quantities never share an axis (residuals in mg and temperature in degC get a
plot each); every displacement plot gets a y range from its own data (so a track of a few cm is not
drawn on a '0'-only axis) and its legend in the corner its curves leave free; the robot's 3D view
looks at the true path (a track that fails by tens of metres would otherwise set the frame).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from accellog.present.rrd.bars2d import nice_ticks
from accellog.present.rrd.entities import (
    DOCS,
    LADDER,
    MAIN_TIMELINE,
    POSES_ACTIVE,
    TEMPERATURE,
    TRACKS,
    WORLD_TRACKS,
    slug_path,
)
from accellog.present.rrd.layout import framed_eye, ladder_bars_view, residual_bars_view, time_panel
from accellog.present.rrd.logs import LADDER_DRIVER

Series = tuple[np.ndarray, np.ndarray]
"""(t (N,) s, values (N,k)) of a plotted series."""


@dataclass
class DemoData:
    """What the layout frames: static-test tracks (label -> displacement, m), robot tracks (label ->
    position, m; the true path under 'truth'), robot position errors (label -> |error|, m)."""

    static_tracks: dict[str, Series] = field(default_factory=dict)
    robot_tracks: dict[str, Series] = field(default_factory=dict)
    robot_errors: dict[str, Series] = field(default_factory=dict)
    workbench_residuals: list[Series] = field(default_factory=list)
    """Residuals (mg) of the ladder steps plotted in the workbench tab."""
    workbench_driver: list[Series] = field(default_factory=list)
    """What they are plotted against (temperature, degC)."""
    calibration_temperature: list[Series] = field(default_factory=list)
    """The calibration session's die temperature (degC)."""
    n_diagnoses: int = 3


LEGEND_BOX = (0.45, 0.4)
"""Share of a plot's width and height a legend of a few lines covers (about)."""


def y_range(values: np.ndarray, pad: float = 0.08) -> tuple[float, float]:
    """(lo, hi) around values with pad of their span on each side (±1 around a constant)."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return -1.0, 1.0
    lo, hi = float(v.min()), float(v.max())
    span = hi - lo
    if span <= 1e-12 * max(1.0, abs(hi)):
        return lo - 1.0, hi + 1.0
    return lo - pad * span, hi + pad * span


def tick_range(values: np.ndarray) -> tuple[float, float]:
    """y_range widened to the nearest 1-2-5 ticks outside it (plus 3 % of the span), so that at
    least three tick values are labelled (the viewer labels the ticks of its own spacing that fall
    inside the range: a range just inside +-20 labels only '0' when it picks a spacing of 20)."""
    lo, hi = y_range(values, pad=0.04)
    ticks = nice_ticks(lo, hi, n=6)
    margin = 0.03 * float(ticks[-1] - ticks[0])
    return float(ticks[0]) - margin, float(ticks[-1]) + margin


def legend_corner(series: Sequence[Series], y_lim: tuple[float, float] | None = None):
    """The plot corner (rrb Corner2D) whose LEGEND_BOX covers the fewest samples of the series."""
    import rerun.blueprint as rrb

    ts = np.concatenate([np.asarray(t, np.float64) for t, _ in series])
    vs = [np.asarray(v, np.float64).reshape(len(t), -1) for t, v in series]
    t_lo, t_hi = float(ts.min()), float(ts.max())
    lo, hi = y_lim if y_lim is not None else y_range(np.concatenate([v.ravel() for v in vs]))
    u = np.concatenate(
        [
            np.repeat((np.asarray(t, np.float64) - t_lo) / max(t_hi - t_lo, 1e-12), v.shape[1])
            for (t, _), v in zip(series, vs, strict=True)
        ]
    )
    w = np.concatenate([((v - lo) / max(hi - lo, 1e-12)).ravel() for v in vs])
    bw, bh = LEGEND_BOX
    boxes = {
        rrb.components.Corner2D.LeftTop: (u < bw) & (w > 1 - bh),
        rrb.components.Corner2D.RightTop: (u > 1 - bw) & (w > 1 - bh),
        rrb.components.Corner2D.LeftBottom: (u < bw) & (w < bh),
        rrb.components.Corner2D.RightBottom: (u > 1 - bw) & (w < bh),
    }
    return min(boxes, key=lambda c: int(np.count_nonzero(boxes[c])))


def whole_range_plot(**kw):
    """A time-series view that always shows its whole time range (the demo's sessions differ in
    length and share the sensor_time timeline, so a cursor-relative window would hide data)."""
    import rerun.blueprint as rrb

    whole = rrb.TimeRange(start=rrb.TimeRangeBoundary.infinite(), end=rrb.TimeRangeBoundary.infinite())
    return rrb.TimeSeriesView(
        time_ranges=rrb.VisibleTimeRange(MAIN_TIMELINE, start=whole.start, end=whole.end),
        axis_x=rrb.TimeAxis(link="Independent", view_range=whole),
        **kw,
    )


def framed_plot(origin: str, name: str, series: Sequence[Series], **kw):
    """whole_range_plot with a y range from the series' own values and the legend in their free corner."""
    import rerun.blueprint as rrb

    if not series:
        return whole_range_plot(origin=origin, name=name, **kw)
    lim = tick_range(np.concatenate([np.asarray(v, np.float64).ravel() for _, v in series]))
    return whole_range_plot(
        origin=origin,
        name=name,
        axis_y=rrb.ScalarAxis(range=lim, zoom_lock=False),
        plot_legend=rrb.PlotLegend(legend_corner(series, lim)),
        **kw,
    )


MIN_TEMP_SPAN_DEGC = 4.0
"""A temperature plot spans at least this much: a chip held at 25 degC reads as a flat line, not as
its +-0.05 degC quantisation noise filling the panel under one tick."""


def temperature_plot(origin: str, name: str, series: Sequence[Series]):
    """whole_range_plot of a temperature (degC), its y range at least MIN_TEMP_SPAN_DEGC."""
    import rerun.blueprint as rrb

    values = np.concatenate([np.asarray(v, np.float64).ravel() for _, v in series]) if series else np.zeros(0)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return whole_range_plot(origin=origin, name=name)
    mid = 0.5 * (float(values.min()) + float(values.max()))
    half = 0.5 * MIN_TEMP_SPAN_DEGC
    lim = tick_range(np.r_[values, mid - half, mid + half])
    return whole_range_plot(origin=origin, name=name, axis_y=rrb.ScalarAxis(range=lim, zoom_lock=False))


def _ends_eye(tracks: Mapping[str, Series]):
    """The static tab's 3D eye: face-on to the tracks' start (the origin) and end points."""
    if not tracks:
        return None
    ends = [np.zeros(3)] + [np.asarray(d, np.float64).reshape(-1, 3)[-1] for _, d in tracks.values()]
    return framed_eye(np.array(ends), face_on=True)


def demo_blueprint(data: DemoData, first: int = 0):
    """The demo's layout: one tab per chapter of the story (static test, calibration, workbench,
    robot), framed on data; first: the tab shown when the recording opens."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Tabs(
            _static_tab(data.static_tracks),
            _calibration_tab(data.calibration_temperature),
            _workbench_tab(data),
            _robot_tab(data),
            active_tab=first,
        ),
        time_panel(),
        collapse_panels=True,
    )


def _calibration_tab(temperature: Sequence[Series] = ()):
    """Raw and calibrated accel, temperature (at least MIN_TEMP_SPAN_DEGC tall); residual per pose
    (named) of each model; parameters."""
    import rerun.blueprint as rrb

    return rrb.Horizontal(
        rrb.Vertical(
            whole_range_plot(
                origin="/accel/raw",
                contents=["$origin/**", f"/{POSES_ACTIVE}/**"],
                name="raw accel (g) + holds",
            ),
            whole_range_plot(origin="/accel/Model_3", name="calibrated accel, Model 3 (g)"),
            temperature_plot(f"/{TEMPERATURE}", "temperature (degC)", temperature),
        ),
        rrb.Vertical(
            rrb.Tabs(
                *[
                    residual_bars_view(m, name=f"{m}: measured - predicted per pose (mg)")
                    for m in ("model1", "model2", "model3")
                ],
                name="residuals per pose",
            ),
            rrb.TextDocumentView(origin=f"/{DOCS}/parameters/model3", name="Model 3 parameters"),
        ),
        column_shares=[3, 2],
        name="1 calibration session",
    )


def _static_tab(tracks: Mapping[str, Series]):
    """Integrated displacement per calibration (one plot each, framed), 3D tracks, tables."""
    import rerun.blueprint as rrb

    return rrb.Horizontal(
        rrb.Grid(
            *[
                framed_plot(f"/{TRACKS}/test/{slug_path(lab)}", f"{lab}: displacement (m)", [s])
                for lab, s in tracks.items()
            ],
            name="static test: integrated displacement per calibration",
        ),
        rrb.Vertical(
            rrb.Spatial3DView(
                origin=f"/{WORLD_TRACKS}/test",
                name="static test tracks 3D (m)",
                eye_controls=_ends_eye(tracks),
            ),
            rrb.Tabs(
                rrb.TextDocumentView(origin=f"/{DOCS}/results/static_test", name="Tables 4 and 5"),
                rrb.TextDocumentView(origin=f"/{DOCS}/results/drift_model", name="drift model"),
            ),
        ),
        name="2 static test",
    )


def _workbench_tab(data: DemoData):
    """The ladder's named bars, the residuals of Model 3 and of the final model (a colour each) and
    the temperature on its own axis below; the ladder table and each diagnosis."""
    import rerun.blueprint as rrb

    return rrb.Horizontal(
        rrb.Vertical(
            ladder_bars_view(),
            framed_plot(
                f"/{LADDER}/steps",
                "calibration residuals (mg): Model 3 vs the final model",
                data.workbench_residuals,
            ),
            framed_plot(f"/{LADDER_DRIVER}", "temperature during the warm-up (degC)", data.workbench_driver),
            row_shares=[4, 4, 2],
        ),
        rrb.Tabs(
            rrb.TextDocumentView(origin=f"/{DOCS}/ladder", name="ladder"),
            *[
                rrb.TextDocumentView(origin=f"/{DOCS}/workbench/step_{i}", name=f"diagnosis {i}")
                for i in range(1, data.n_diagnoses + 1)
            ],
        ),
        column_shares=[3, 2],
        name="3 workbench",
    )


def _robot_tab(data: DemoData):
    """3D tracks framed on the true path; position per calibration (one plot each); position errors;
    ZUPT stops (a plot of their own: 0/1 is no position); the error table."""
    import rerun.blueprint as rrb

    truth = data.robot_tracks.get("truth")
    eye = framed_eye(truth[1]) if truth is not None else None
    plots = [
        framed_plot(f"/{TRACKS}/robot/{slug_path(lab)}", f"{lab}: position (m)", [s])
        for lab, s in data.robot_tracks.items()
    ]
    errors = list(data.robot_errors.values())
    return rrb.Horizontal(
        rrb.Spatial3DView(
            origin=f"/{WORLD_TRACKS}/robot", name="robot tracks vs truth (m)", eye_controls=eye
        ),
        rrb.Vertical(
            *([rrb.Grid(*plots, name="robot position per calibration")] if plots else []),
            framed_plot("/errors/robot", "position error (m)", errors),
            whole_range_plot(origin="/zupt/robot", name="ZUPT stops (1: stopped)"),
            rrb.TextDocumentView(origin=f"/{DOCS}/results/robot_tracks", name="position errors"),
            row_shares=[5, 3, 1, 2] if plots else [3, 1, 2],
        ),
        column_shares=[1, 1],
        name="4 moving robot",
    )
