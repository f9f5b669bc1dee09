"""Blueprints: the saved layout of a recording (one tab per question) and of the live view."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from accellog.present.rrd.entities import (
    CHARTS,
    DOCS,
    EVENTS_LOST,
    LADDER,
    LIVE,
    MAIN_TIMELINE,
    POSES_ACTIVE,
    RESIDUALS,
    TEMPERATURE,
    TRACKS,
)

LEGEND_MAX_POSES = 6
"""With more holds than this, a sample view hides its legend (one line per hold) and names its colours."""


def time_panel():
    """Time panel on sensor_time, following new data, collapsed (shared by every blueprint)."""
    import rerun.blueprint as rrb

    return rrb.TimePanel(timeline=MAIN_TIMELINE, play_state="following", state="collapsed")


def build_blueprint(entities: Mapping[str, str], ends_m: Sequence[np.ndarray] = ()):
    """Layout for what was logged: sample streams with pose windows, temperature + events, tracks
    (time series + 3D side by side, the 3D eye framed on the tracks' start and ends_m, m), residual
    and ladder charts, documents and logs. With two or more tracks (replay, compare) the tracks take
    the main area, one auto-scaled plot each."""
    import rerun.blueprint as rrb

    roles: dict[str, list[str]] = {}
    for ent, role in entities.items():
        roles.setdefault(role, []).append(ent)
    tracks = roles.get("track", [])  # logged order (raw first in replays)
    track_views = [rrb.TimeSeriesView(origin=f"/{e}", name=f"{e.split('/', 1)[1]} (m)") for e in tracks]
    world = None
    if "track3d" in roles:
        eye = framed_eye(np.array([np.zeros(3), *ends_m]), face_on=True) if len(ends_m) else None
        world = rrb.Spatial3DView(origin="/world", name="tracks 3D (m)", eye_controls=eye)
    texts: list[rrb.TextDocumentView | rrb.TextLogView] = [
        rrb.TextDocumentView(origin=f"/{e}", name=e[len(DOCS) + 1 :]) for e in sorted(roles.get("doc", []))
    ]
    if "textlog" in roles:
        texts.append(rrb.TextLogView(origin="/", name="events and poses"))
    story = _story_tabs(roles)  # a workbench: the search, the residual it removed first, every driver
    root = _arrange(_sample_views(roles), track_views, world, _chart_views(roles, scatter=not story), texts)
    if story:
        rest = "session and ladder" if "ladder_bar" in roles else "session and tables"
        root = rrb.Tabs(*story, rrb.Vertical(root, name=rest))
    return rrb.Blueprint(root, time_panel(), collapse_panels=True)


def _story_tabs(roles: Mapping[str, list[str]]) -> list:
    """A workbench recording's own tabs: the search (every model tried, its held-out residual) over
    the ladder, and the residual against the driver it follows, before and after, per axis."""
    import rerun.blueprint as rrb

    tabs: list[rrb.Vertical | rrb.Tabs] = []
    if "search2d" in roles:
        search = rrb.Spatial2DView(
            origin=f"/{CHARTS}/search",
            name="the search: the error of every model tried, held out when a held-out session is given (log scale)",
            visual_bounds=rrb.VisualBounds2D(x_range=(-80.0, 1210.0), y_range=(-50.0, 400.0)),
        )
        views = [search, ladder_bars_view()] if "ladder_bar" in roles else [search]
        tabs.append(rrb.Vertical(*views, row_shares=[3, 2][: len(views)], name="the search"))
    main = _scatter_views(roles, "scatter2d_main")
    verdict = [e for e in roles.get("doc", []) if e == f"{DOCS}/verdict"]  # a diagnosis: said above its plots
    for d, vs in main.items():
        said = [rrb.TextDocumentView(origin=f"/{e}", name="what is missing") for e in verdict]
        tabs.append(
            rrb.Vertical(
                *said,
                *vs,
                row_shares=[1] * len(said) + [2] * len(vs),
                name=f"residual vs {d}: before / after",
            )
        )
        verdict = []
    # views of their own: a view placed in two containers (the tab above and here) draws in neither
    every = {**_scatter_views(roles, "scatter2d_main"), **_scatter_views(roles, "scatter2d")}
    if tabs and every:  # each driver as large as the first, one tab each
        tabs.append(rrb.Tabs(*(rrb.Vertical(*vs, name=f"residual vs {d}") for d, vs in every.items()),
                             name="residual vs every driver"))  # fmt: skip
    return tabs


def _scatter_views(roles: Mapping[str, list[str]], role: str) -> dict[str, list]:
    """Residual-vs-driver plots (present.residual_views): driver title -> one 2D view per axis, its
    frame and every fit's points and lines on that axis."""
    import rerun.blueprint as rrb

    from accellog.present.residual_views import BOUNDS, DRIVERS, FRAME

    frames: dict[str, list[str]] = {}  # driver -> axes (logged order)
    members: dict[tuple[str, str], list[str]] = {}  # (driver, axis) -> the fits' entities
    for ent in roles.get(role, []):
        parts = ent.split("/")
        if len(parts) < 4:
            continue
        d, leaf = parts[1], parts[2]
        if leaf.startswith(FRAME):
            axes = frames.setdefault(d, [])
            if leaf[len(FRAME) :] not in axes:
                axes.append(leaf[len(FRAME) :])
        else:
            members.setdefault((d, parts[3].removeprefix("contribution_")), []).append(ent)
    out = {}
    bounds = rrb.VisualBounds2D(x_range=BOUNDS[:2], y_range=BOUNDS[2:])
    for d, axes in frames.items():
        title = DRIVERS.get(d, "pose" if d == "pose" else d)
        out[title] = [
            rrb.Spatial2DView(
                origin=f"/{_scatter_root(d)}",
                contents=[f"/{_scatter_root(d)}/{FRAME}{a}/**", *(f"/{e}" for e in members.get((d, a), []))],
                name=f"residual {a} (mg) vs {title}",
                visual_bounds=bounds,
            )
            for a in axes
        ]
    return out


def _scatter_root(driver: str) -> str:
    """Entity root of one driver's residual plots."""
    from accellog.present.residual_views import SCATTER

    return f"{SCATTER}/{driver}"


def _sample_views(roles: Mapping[str, list[str]]) -> list:
    """One time series per sample stream (logged order) with the pose windows and detected still
    intervals, and temperature + lost samples."""
    import rerun.blueprint as rrb

    has_poses = "poses" in roles
    many = len(roles.get("poses", [])) > LEGEND_MAX_POSES
    samples = []
    for ent in [e for r, es in roles.items() if r.startswith("samples:") for e in es]:  # logged order
        contents = ["$origin/**"] + ([f"/{POSES_ACTIVE}/**"] if has_poses else [])
        contents += [f"/{e}" for e in roles.get("detected", [])]  # detected still intervals (hand-held)
        name = ent.replace("/", " ")
        legend = None
        if many:  # a legend of 24 pose names hides the plot: the colours are said in the title instead
            name += ": x red, y green, z blue; grey steps: holds (named in 'events and poses')"
            legend = rrb.PlotLegend(visible=False)
        samples.append(rrb.TimeSeriesView(origin=f"/{ent}", contents=contents, name=name, plot_legend=legend))
    if "temperature" in roles or "lost" in roles:
        samples.append(
            rrb.TimeSeriesView(
                origin="/",
                contents=[f"/{TEMPERATURE}", f"/{EVENTS_LOST}"],
                name="temperature (degC) + lost samples",
            )
        )
    return samples


def _chart_views(roles: Mapping[str, list[str]], scatter: bool = True) -> list:
    """Residual-vs-driver plots (one column per driver; scatter=False: none, they have tabs of their
    own), residual bars per model, ladder bars and steps."""
    import rerun.blueprint as rrb

    charts = []
    plots = (
        {**_scatter_views(roles, "scatter2d_main"), **_scatter_views(roles, "scatter2d")} if scatter else {}
    )
    for title, views in plots.items():
        charts.append(rrb.Vertical(*views, name=f"residual vs {title}"))
    for model in sorted({e.split("/")[1] for e in roles.get("residual_bar", [])}):
        charts.append(residual_bars_view(model))
    if "field3d" in roles:  # a fit from stops (present.field_views)
        charts.append(_field_views(roles))
    if "ladder_bar" in roles:
        charts.append(ladder_bars_view())
    if "ladder_step" in roles:
        steps = rrb.TimeSeriesView(origin=f"/{LADDER}/steps", name="ladder residuals (mg)")
        driver = [
            rrb.TimeSeriesView(origin=f"/{e}", name=e.split("/")[-1]) for e in roles.get("ladder_driver", [])
        ]
        charts.append(_group([steps, *driver]))
    return charts


def _field_views(roles: Mapping[str, list[str]]):
    """A fit from stops: the stops on the sphere, |f| - g per stop before/after, the gyro bias against
    temperature (its own timeline, present.field_views.GYRO_TEMP_TIMELINE)."""
    import rerun.blueprint as rrb

    views = [
        rrb.Spatial3DView(origin="/field/sphere", name="stops: gravity directions and van Hees caps"),
        rrb.Spatial2DView(
            origin=f"/{CHARTS}/field/norm_residual", name="|f| - g per stop (mg): before, after"
        ),
    ]
    if "field_gyro" in roles:
        views.append(
            rrb.TimeSeriesView(origin="/field/gyro_bias", name="gyro bias (deg/s) vs temperature_mdegC")
        )
    return rrb.Vertical(*views, name="stops")


def residual_bars_view(model: str, name: str | None = None):
    """The named bar chart (present.rrd.bars2d) of a model's residual per pose and axis (mg)."""
    import rerun.blueprint as rrb

    return rrb.Spatial2DView(origin=f"/{CHARTS}/{RESIDUALS}/{model}", name=name or f"residuals {model} (mg)")


def _group(views, kind=None):
    """The views that are not None: None, the one view, or kind(*views) (default rrb.Vertical)."""
    import rerun.blueprint as rrb

    views = [v for v in views if v is not None]
    if not views:
        return None
    return views[0] if len(views) == 1 else (kind or rrb.Vertical)(*views)


def _arrange(samples: list, track_views: list, world, charts: list, texts: list):
    """The root container: tracks in the main area with two or more (replay / compare), else the
    sample streams on the left and tracks, charts and documents on the right."""
    import rerun.blueprint as rrb

    if len(track_views) >= 2:  # replay / compare: the tracks are the question
        top = [
            rrb.Grid(*track_views, name="displacement per track"),
            _group([world, _group(texts, rrb.Tabs)]),
        ]
        rows = [rrb.Horizontal(*[c for c in top if c is not None], column_shares=[3, 2])]
        bottom = _group([*samples, *charts], rrb.Tabs)
        if bottom is not None:
            rows.append(bottom)
        return rows[0] if len(rows) == 1 else rrb.Vertical(*rows, row_shares=[3, 1])
    left = _group(samples if len(samples) <= 3 else [rrb.Tabs(*samples[:-1]), samples[-1]])
    right = _group(
        [
            _group([*track_views, world], rrb.Horizontal),
            _group(charts, rrb.Tabs),
            _group(texts, rrb.Tabs),
        ]
    )
    cols = [c for c in (left, right) if c is not None]
    return (
        rrb.Horizontal(*cols, column_shares=[3, 2])
        if len(cols) == 2
        else (cols[0] if cols else rrb.Vertical())
    )


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


def ladder_bars_view(name: str = "model ladder: each step's fit, held-out and drift error (log scale)"):
    """The ladder's named bar chart (present.rrd.bars2d): per metric one bar per step, coloured by
    step (the legend names each step's model), on a log scale."""
    import rerun.blueprint as rrb

    return rrb.Spatial2DView(origin=f"/{CHARTS}/{LADDER}", name=name)


def framed_eye(points_m: np.ndarray, face_on: bool = False):
    """Orbital 3D eye looking at the centre of points_m (N,3, m) from a distance that shows them
    all: from above and aside (z up), or with face_on along the direction in which the points spread
    least (their smallest principal axis, tilted a little) with their widest spread upwards, so that
    they and their labels spread over the picture instead of lining up behind each other."""
    import rerun.blueprint as rrb

    p = np.asarray(points_m, dtype=np.float64).reshape(-1, 3)
    lo, hi = p.min(axis=0), p.max(axis=0)
    centre = 0.5 * (lo + hi)
    size = max(float(np.linalg.norm(hi - lo)), 1.0)
    direction, up, distance = np.array([-0.55, -1.0, 0.9]), np.array([0.0, 0.0, 1.0]), 1.5
    if face_on and p.shape[0] >= 3:
        axes = np.linalg.svd(p - p.mean(axis=0), full_matrices=False)[2]
        normal = axes[-1] * (1.0 if axes[-1][2] >= 0 else -1.0)  # from the upper side
        # the widest spread runs up the picture and the next one at 35 deg to it, so that points
        # apart along either are apart vertically too: the (wide) labels stack, not overlap
        up = np.cos(np.radians(35.0)) * axes[0] + np.sin(np.radians(35.0)) * axes[1]
        direction, distance = normal + 0.2 * axes[1], 1.1
    direction = direction / np.linalg.norm(direction)
    return rrb.EyeControls3D(
        kind=rrb.Eye3DKind.Orbital,
        position=(centre + distance * size * direction).tolist(),
        look_target=centre.tolist(),
        eye_up=up.tolist(),
    )
