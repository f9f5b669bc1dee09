"""Where the model fails: window residuals against each driver signal, in a Rerun recording.

One plot per (driver, axis): x = the driver (temperature in degC, its rate in degC/s, time in s,
time in pose in s, the reading f_i and f_i f_j in g), y = the window residual on that axis (mg), every
fit overlaid in its own colour (the calibration's colour in every panel: a workbench's start model
is 'before', its final model 'after'), passes kept apart (heating windows filled, cooling windows
lighter, so a hysteresis or a heat/cool disagreement is not averaged away), and what the added
effects predict drawn over the residual they explain (darker dots). Rerun has no x-y plot with
axes yet, so each plot is a 2D view with its own frame, zero line, tick labels and legend; the
plots are wide (W x H view units) for wide views. One more plot per axis puts the windows by pose
(`residual_vs/pose/...`): x = the pose, labelled with its name, every window kept (a per-pose
mean would let heating and cooling passes cancel).

    contribution of the added effects = predict(final model) - predict(start model), per window (mg)
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from accellog.calibrate.model.fit import FitResult, obs_drivers
from accellog.core.session import ObsTable
from accellog.present.rrd.bars2d import nice_ticks
from accellog.present.rrd.entities import AXES, TRACK_COLORS, slug


class WindowResiduals(Protocol):
    """What the residual plots read of a fit (FitResult) or of an evaluation: its (n,3) window
    residuals in g."""

    @property
    def residual_g(self) -> np.ndarray: ...


SCATTER = "residual_vs"
"""Entity root of the residual-vs-driver plots (role 'scatter2d' in the blueprint)."""
DRIVERS = {
    "temp_degC": "temperature (degC)",
    "dtemp_degC_per_s": "dT/dt (degC/s)",
    "t_s": "time (s)",
    "t_in_pose_s": "time in pose (s)",
    "f_x_g": "reading f_x (g)",
    "f_y_g": "reading f_y (g)",
    "f_z_g": "reading f_z (g)",
    "f_xf_y_g2": "f_x f_y (g^2)",
    "f_xf_z_g2": "f_x f_z (g^2)",
    "f_yf_z_g2": "f_y f_z (g^2)",
}
"""Driver signals plotted, with their axis titles: the model drivers, and the window's reading per
axis f_i (a residual quadratic in f_i, i.e. linear in f_i^2, shows as a parabola) and the products
f_i f_j (cross-axis nonlinearity). Yaw is not plotted: a static accelerometer cannot see rotation
about gravity."""


def driver_values(obs: ObsTable) -> dict[str, np.ndarray]:
    """Every driver of DRIVERS on the windows of obs (model drivers, readings f_i and f_i f_j in g)."""
    drv = dict(obs_drivers(obs))
    f = np.asarray(obs.meas_g, float)
    for i, a in enumerate("xyz"):
        drv[f"f_{a}_g"] = f[:, i]
    for i, j in ((0, 1), (0, 2), (1, 2)):
        drv[f"f_{'xyz'[i]}f_{'xyz'[j]}_g2"] = f[:, i] * f[:, j]
    return drv


W, H = 1200.0, 200.0
"""Plot frame in view units (x: driver range, y: residual range): wide, as the views that show it."""
FRAME = "frame_"
"""Entity of a plot's frame, ticks and legend: ``residual_vs/{driver}/frame_{axis}`` (the fits'
points are at ``residual_vs/{driver}/{label}/{axis}``); role ``scatter2d`` (``scatter2d_main``: the
driver the residual follows, given its own tab)."""
BOUNDS = (-90.0, W + 10.0, -H / 2 - 40.0, H / 2 + 54.0)
"""What a view of one plot shows (x0, x1, y0, y1 in view units): the frame and its labels."""


@dataclass
class Panel:
    """One fit's residuals (mg; (n, 3) per axis, or (n, 1) the gravity norm) against driver `driver`."""

    driver: str
    label: str
    x: np.ndarray
    residual_mg: np.ndarray
    heating: np.ndarray
    contribution_mg: np.ndarray | None = None


def panels(
    obs: ObsTable,
    fits: Mapping[str, WindowResiduals],
    contributions: Mapping[str, np.ndarray] | None = None,
) -> list[Panel]:
    """Panels for every driver present (not constant) and every labelled fit; contributions
    (label -> (n,3) g) are drawn over that label's residual."""
    drv = driver_values(obs)
    rate = drv.get("dtemp_degC_per_s", np.zeros(obs.n))
    out = []
    for d in DRIVERS:
        if d not in drv or np.ptp(drv[d]) == 0:
            continue
        for label, res in fits.items():
            c = None if contributions is None or label not in contributions else 1e3 * contributions[label]
            out.append(Panel(d, label, drv[d], 1e3 * np.asarray(res.residual_g), rate >= 0, c))
    return out


def contribution_g(base: FitResult, with_effect: FitResult, obs: ObsTable) -> np.ndarray:
    """What the added effect predicts per window (g): prediction of model + effect minus the base
    model's prediction, both at their fitted parameters."""
    return np.asarray(with_effect.predicted_g) - np.asarray(base.predicted_g)


def fit_colors(labels, colors: Mapping[str, tuple[int, int, int]] | None = None) -> dict:
    """Colour per fit: the caller's (a calibration's colour in every panel of a recording, e.g. its
    ladder step's), else the track colours in order."""
    given = dict(colors or {})
    return {k: tuple(given.get(k, TRACK_COLORS[i % len(TRACK_COLORS)])) for i, k in enumerate(labels)}


def _light(rgb) -> np.ndarray:
    c = np.asarray(rgb, float)
    return (c + (255.0 - c) * 0.55).astype(np.uint8)


def _frame(rec, ent: str, role: str, x_ticks: list[tuple[float, str]], y_max: float, legend, width=W) -> None:
    """Frame, zero line, tick labels (x below, y on the left in mg) and a coloured legend above."""
    import rerun as rr

    box = [[0, -H / 2], [width, -H / 2], [width, H / 2], [0, H / 2], [0, -H / 2]]
    rec.log_static(
        f"{ent}/frame",
        rr.LineStrips2D([box, [[0, 0], [width, 0]]], colors=[(150, 150, 150), (110, 110, 110)], radii=0.6),
        role,
    )
    ys = [y_max, y_max / 2, 0.0, -y_max / 2, -y_max]
    pos = [[x, H / 2 + 16 + (14 if len(x_ticks) > 12 and k % 2 else 0)] for k, (x, _) in enumerate(x_ticks)]
    pos += [[-48.0, -y / y_max * (H / 2)] for y in ys]
    txt = [t for _, t in x_ticks] + [f"{y:+.3g} mg" if y else "0" for y in ys]
    rec.log_static(
        f"{ent}/ticks", rr.Points2D(pos, labels=txt, radii=0.1, colors=[(200, 200, 200)] * len(txt)), role
    )
    step = width / max(len(legend), 1)
    rec.log_static(
        f"{ent}/legend",
        rr.Points2D(
            [[(j + 0.5) * step, -H / 2 - 18] for j in range(len(legend))],
            labels=[t for t, _ in legend],
            colors=[c for _, c in legend],
            radii=0.1,
        ),
        role,
    )


def _marks(rec, ent: str, role: str, at: list[tuple[float, str]]) -> None:
    """Labelled vertical lines at view x positions (clipped to the frame)."""
    import rerun as rr

    at = [(min(max(x, 0.0), W), t) for x, t in at]
    strips = [[[x, -H / 2], [x, H / 2]] for x, _ in at]
    rec.log_static(f"{ent}/marks", rr.LineStrips2D(strips, colors=[(230, 180, 60)], radii=1.2), role)
    rec.log_static(
        f"{ent}/mark_labels",
        rr.Points2D(
            [[x + (80.0 if x < W / 2 else -80.0), -H / 2 + 10] for x, _ in at],
            labels=[t for _, t in at],
            radii=0.1,
            colors=[(230, 180, 60)],
        ),
        role,
    )


def _short(label: str, labels) -> str:
    """'final <start>+a+b' as 'final: + a + b' beside 'start <start>' (two model names side by side
    overlap in the legend)."""
    starts = [k[len("start ") :] for k in labels if k.startswith("start ")]
    if starts and label.startswith(f"final {starts[0]}+"):
        return "final: + " + " + ".join(label[len(f"final {starts[0]}+") :].split("+"))
    return label


def _legend(
    labels, colors, axis: str, lines: bool, cooling: bool = True, dots: str = "what the added effects predict"
) -> list[tuple[str, tuple]]:
    what = "residual" if axis == "norm" else f"residual {axis}"
    out = [
        (f"{_short(k, labels)}: {what}" + (" (light: cooling)" if cooling else ""), colors[k]) for k in labels
    ]
    dark = tuple(int(0.5 * v) for v in colors[labels[0]])
    return out + ([(f"dark dots: {dots}", dark)] if lines else [])


def log_panels(
    rec,
    items: list[Panel],
    colors: Mapping[str, tuple[int, int, int]] | None = None,
    main: str | None = None,
    marks: Sequence[tuple[float, str]] = (),
    dots: str = "what the added effects predict",
) -> None:
    """Log the panels: per driver and axis one plot with every fit's residuals overlaid in its own
    colour (colors: label -> RGB, see fit_colors), one y scale per axis (mg); main: the driver the
    residual follows (role scatter2d_main: its own tab in the blueprint); marks: (driver value,
    label) drawn as labelled vertical lines on the main driver's plots (e.g. an exported span); dots:
    what the contributions are, in the legend."""
    import rerun as rr

    by_driver: dict[str, list[Panel]] = {}
    for p in items:
        by_driver.setdefault(p.driver, []).append(p)
    for d, ps in by_driver.items():
        role = "scatter2d_main" if d == main else "scatter2d"
        cols = fit_colors([p.label for p in ps], colors)
        x_lo = float(min(np.min(p.x) for p in ps))
        x_hi = float(max(np.max(p.x) for p in ps))

        def sx(x, lo=x_lo, hi=x_hi):
            return (np.asarray(x, float) - lo) / max(hi - lo, 1e-12) * W

        ticks = [float(v) for v in nice_ticks(x_lo, x_hi) if x_lo <= v <= x_hi] or [x_lo, x_hi]
        x_ticks = [(float(sx(v)), f"{v:g}") for v in ticks]
        axes = AXES if ps[0].residual_mg.shape[1] == 3 else ("norm",)
        for i, a in enumerate(axes):
            ys = [np.abs(p.residual_mg[:, i]) for p in ps]
            ys += [np.abs(p.contribution_mg[:, i]) for p in ps if p.contribution_mg is not None]
            y_max = float(nice_ticks(0.0, max(float(max(np.max(y) for y in ys)), 1e-6), n=3)[-1])
            lines = any(p.contribution_mg is not None for p in ps)
            cooling = any(not np.all(p.heating) for p in ps)
            legend = _legend([p.label for p in ps], cols, a, lines, cooling, dots)
            _frame(rec, f"{SCATTER}/{slug(d)}/{FRAME}{a}", role, x_ticks, y_max, legend)
            if marks and d == main:
                _marks(rec, f"{SCATTER}/{slug(d)}/{FRAME}{a}", role, [(float(sx(v)), t) for v, t in marks])
            for p in ps:
                ent = f"{SCATTER}/{slug(d)}/{slug(p.label)}"
                col = np.asarray(cols[p.label], np.uint8)
                shade = np.where(p.heating[:, None], col, _light(col)).astype(np.uint8)
                pts = np.column_stack([sx(p.x), -p.residual_mg[:, i] / y_max * (H / 2)])
                rec.log_static(f"{ent}/{a}", rr.Points2D(pts, colors=shade, radii=4.0), role)
                if p.contribution_mg is not None:  # dots: a line would zigzag between poses
                    c = np.column_stack([sx(p.x), -p.contribution_mg[:, i] / y_max * (H / 2)])
                    dark = tuple(int(v) for v in (0.5 * col))
                    rec.log_static(f"{ent}/contribution_{a}", rr.Points2D(c, colors=[dark], radii=1.8), role)


def log_pose_panels(
    rec,
    obs: ObsTable,
    fits: Mapping[str, WindowResiduals],
    colors: Mapping[str, tuple[int, int, int]] | None = None,
) -> None:
    """Window residuals (mg) by pose, per axis one plot with the fits side by side at each pose
    (pose k at x slot k, its name below the frame, alternating rows), every window kept, cooling
    windows lighter; each fit in its colour (fit_colors)."""
    import rerun as rr

    pid = np.asarray(obs.pose_id, int)
    names = list(obs.pose_names)
    if not fits or len(names) < 2:
        return
    used = np.unique(pid)
    slot = {int(p): i for i, p in enumerate(used)}
    xs = np.array([slot[int(p)] for p in pid], float)
    rate = obs_drivers(obs).get("dtemp_degC_per_s", np.zeros(obs.n))
    cols = fit_colors(list(fits), colors)
    n = len(fits)

    def sx(x):
        return (np.asarray(x, float) + 0.5) / used.size * W

    x_ticks = [(float(sx(i)), names[int(p)]) for i, p in enumerate(used)]
    for i, a in enumerate(AXES):
        y_max = max(float(np.max(np.abs(r.residual_g[:, i]))) * 1e3 for r in fits.values())
        y_max = float(nice_ticks(0.0, max(y_max, 1e-6), n=3)[-1])
        ent = f"{SCATTER}/pose/{FRAME}{a}"
        _frame(rec, ent, "scatter2d", x_ticks, y_max, _legend(list(fits), cols, a, False))
        for j, (label, res) in enumerate(fits.items()):
            col = np.asarray(cols[label], np.uint8)
            shade = np.where((rate >= 0)[:, None], col, _light(col)).astype(np.uint8)
            off = 0.0 if n == 1 else 0.5 * (j / (n - 1) - 0.5)
            r_mg = 1e3 * np.asarray(res.residual_g, float)[:, i]
            pts = np.column_stack([sx(xs + off), -r_mg / y_max * (H / 2)])
            rec.log_static(
                f"{SCATTER}/pose/{slug(label)}/{a}", rr.Points2D(pts, colors=shade, radii=4.0), "scatter2d"
            )


def log_residuals_vs_drivers(
    rec,
    obs: ObsTable,
    fits: Mapping[str, WindowResiduals],
    contributions: Mapping[str, np.ndarray] | None = None,
    colors: Mapping[str, tuple[int, int, int]] | None = None,
    main: str | None = None,
) -> None:
    """Residual-vs-driver plots of the labelled fits (e.g. {'before: model3': ..., 'after: ...': ...}),
    and the window residuals by pose (named); colors and main: see log_panels."""
    log_panels(rec, panels(obs, fits, contributions), colors, main)
    log_pose_panels(rec, obs, fits, colors)


def log_diagnosis_residuals(rec, diag, obs: ObsTable) -> None:
    """diagnose --rrd: the model's residuals against each driver with the chosen candidate's
    predicted contribution drawn over them, and the residuals once the candidate is added; the
    driver they follow (followed_driver) in a tab of its own, first."""
    before = f"{diag.model.name}"
    fits = {before: diag.fit}
    contrib = None
    if diag.best is not None and diag.best in diag.fits:
        after = diag.fits[diag.best]
        fits[f"+{diag.best}"] = after
        contrib = {before: contribution_g(diag.fit, after, obs)}
    log_residuals_vs_drivers(rec, obs, fits, contrib, main=followed_driver(diag))


def log_workbench_residuals(
    rec,
    obs: ObsTable,
    start: FitResult,
    final: FitResult,
    colors: tuple[tuple[int, int, int], tuple[int, int, int]] | None = None,
    follows: str | None = None,
) -> None:
    """workbench --rrd: residuals of the start model (before, with what the added effects predict
    drawn over them) and of the final model (after), against each driver; colors: (start, final),
    e.g. their ladder steps' colours; follows: the driver the start model's residual follows (its
    own tab), default the temperature when it varies."""
    fits = {f"start {start.model.name}": start}
    contrib = None
    if final.model.name != start.model.name:
        fits[f"final {final.model.name}"] = final
        contrib = {f"start {start.model.name}": contribution_g(start, final, obs)}
    cols = None if colors is None else dict(zip(fits, colors, strict=False))
    main = follows if follows in DRIVERS else ("temp_degC" if follows is None else None)
    log_residuals_vs_drivers(rec, obs, fits, contrib, cols, main)


VERDICT = "verdict"
"""The document a diagnosis recording opens with (above the residual it explains)."""


def verdict_markdown(d) -> str:
    """A diagnosis in a line it can be read by at a glance (what is missing and what adding it does
    to chi2/dof), then its whole verdict and first advice."""
    if d.best is not None and d.best in d.fits:
        head = (
            f"missing: {d.best} (chi2/dof {d.fit.chi2_dof:.3g} -> {d.fits[d.best].chi2_dof:.3g} when added)"
        )
    else:
        head = "missing: an effect no candidate explains" if d.missing else "nothing missing"
    return (
        "\n".join([f"## {d.model.name}: {head}", "", d.verdict, "", *(f"- {a}" for a in d.advice[:3])]) + "\n"
    )


def followed_driver(diagnosis) -> str | None:
    """The driver of DRIVERS the residual of a diagnosis follows most (its strongest significant
    driver signal), None when no plotted driver is significant."""
    for s in getattr(diagnosis, "driver_signals", None) or []:
        if s.get("significant") and s.get("signal") in DRIVERS:
            return str(s["signal"])
    return None


def write_diagnosis_rrd(path, session, d, obs) -> None:
    """A Rerun recording of a diagnosis: the session's samples (session: a Session, or None for an
    observation table), the verdict and candidates, the residuals per pose and per window (mg)."""
    from accellog.present.rrd.recording import RunRecording
    from accellog.present.views import log_diagnosis, log_session

    with RunRecording(f"save:{path}") as rec:
        if session is not None:
            log_session(rec, session)
        rec.log_document(VERDICT, verdict_markdown(d))
        log_diagnosis(rec, d, obs)
        log_diagnosis_residuals(rec, d, obs)
        rec.log_series(
            "residuals/windows",
            np.asarray(obs.t_s, float),
            np.asarray(d.fit.residual_g, float) * 1000.0,
            [f"{d.model.name} residual {a} (mg)" for a in "xyz"],
            points=True,
        )
