"""Where the model fails: window residuals against each driver signal, in a Rerun recording.

One scatter plot per (driver, model): x = the driver (temperature in degC, its rate in degC/s,
time in s, time in pose in s, the reading f_i and f_i f_j in g), y = the window residual per axis (mg, axis colours x red, y green,
z blue), passes kept apart (heating windows filled, cooling windows lighter, so a hysteresis or a
heat/cool disagreement is not averaged away), and the candidate's predicted contribution drawn
over the residual it explains (a line per axis). Rerun has no x-y plot with axes yet, so each plot
is a 2D view with its own frame, zero line and tick labels; all models of one driver share the y
scale (mg) so 'before' and 'after' compare at a glance. One more plot per model puts the windows
by pose (`residual_vs/pose/...`): x = the pose, labelled with its name (not an index), every window
kept (a per-pose mean would let heating and cooling passes cancel).

    contribution of a candidate = predict(model + effect) - predict(model), per window (mg)
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from accellog.calibrate.model.fit import FitResult, obs_drivers
from accellog.core.session import ObsTable
from accellog.present.rrd.entities import AXIS_COLORS, slug

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


W, H = 400.0, 240.0
"""Plot frame in view units (x: driver range, y: residual range)."""


@dataclass
class Panel:
    """One scatter plot: residuals (mg; (n, 3) per axis, or (n, 1) the gravity norm) of `label`
    against driver `driver`."""

    driver: str
    label: str
    x: np.ndarray
    residual_mg: np.ndarray
    heating: np.ndarray
    contribution_mg: np.ndarray | None = None


def panels(
    obs: ObsTable,
    fits: Mapping[str, FitResult],
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


def _ticks(lo: float, hi: float) -> list[float]:
    return [lo, 0.5 * (lo + hi), hi]


def log_panels(rec, items: list[Panel]) -> None:
    """Log the panels (one 2D view each, grouped per driver in the blueprint)."""
    import rerun as rr

    by_driver: dict[str, list[Panel]] = {}
    for p in items:
        by_driver.setdefault(p.driver, []).append(p)
    for d, ps in by_driver.items():
        x_lo = float(min(np.min(p.x) for p in ps))
        x_hi = float(max(np.max(p.x) for p in ps))
        ys = [np.abs(p.residual_mg) for p in ps] + [
            np.abs(p.contribution_mg) for p in ps if p.contribution_mg is not None
        ]
        y_max = max(float(max(np.max(y) for y in ys)), 1e-6)

        def sx(x, lo=x_lo, hi=x_hi):
            return (np.asarray(x, float) - lo) / max(hi - lo, 1e-12) * W

        def sy(y, m=y_max):
            return -np.asarray(y, float) / m * (H / 2)  # view y grows downwards: positive residual up

        for p in ps:
            ent = f"{SCATTER}/{slug(d)}/{slug(p.label)}"
            frame = [[0, -H / 2], [W, -H / 2], [W, H / 2], [0, H / 2], [0, -H / 2]]
            rec.log_static(
                f"{ent}/frame",
                rr.LineStrips2D(
                    [frame, [[0, 0], [W, 0]]], colors=[(150, 150, 150), (110, 110, 110)], radii=0.6
                ),
                "scatter2d",
            )
            tick_pos = [[sx(v), H / 2 + 14] for v in _ticks(x_lo, x_hi)]
            tick_pos += [[-8, float(sy(v))] for v in (y_max, 0.0, -y_max)]
            tick_txt = [f"{v:.3g}" for v in _ticks(x_lo, x_hi)] + [
                f"{v:+.3g} mg" for v in (y_max, 0.0, -y_max)
            ]
            rec.log_static(
                f"{ent}/ticks",
                rr.Points2D(tick_pos, labels=tick_txt, radii=0.1, colors=[(200, 200, 200)] * len(tick_txt)),
                "scatter2d",
            )
            axes = "xyz" if p.residual_mg.shape[1] == 3 else ("norm",)
            legend = (
                "x red, y green, z blue (light: cooling); lines: what the added effects predict"
                if len(axes) == 3
                else "gravity-norm residual |f| - g per window (light: cooling)"
            )
            rec.log_static(
                f"{ent}/legend", rr.Points2D([[W / 2, -H / 2 - 12]], labels=[legend], radii=0.1), "scatter2d"
            )
            for i, a in enumerate(axes):
                col = np.array(AXIS_COLORS[i] if len(axes) == 3 else (230, 230, 230))
                light = (col + (255 - col) * 0.6).astype(int) if len(axes) == 3 else np.array([130, 130, 130])
                colors = np.where(p.heating[:, None], col, light).astype(np.uint8)
                pts = np.column_stack([sx(p.x), sy(p.residual_mg[:, i])])
                rec.log_static(f"{ent}/{a}", rr.Points2D(pts, colors=colors, radii=2.2), "scatter2d")
                if p.contribution_mg is not None:
                    o = np.argsort(p.x, kind="stable")
                    line = np.column_stack([sx(p.x[o]), sy(p.contribution_mg[o, i])])
                    rec.log_static(
                        f"{ent}/contribution_{a}",
                        rr.LineStrips2D([line], colors=[tuple(int(c) for c in col)], radii=1.0),
                        "scatter2d",
                    )


def log_pose_panels(rec, obs: ObsTable, fits: Mapping[str, FitResult]) -> None:
    """Window residuals (mg) by pose, one 2D view per fit: pose k at x slot k (its name below the
    frame), axes side by side (x, y, z at k - 0.25, k, k + 0.25), cooling windows lighter."""
    import rerun as rr

    pid = np.asarray(obs.pose_id, int)
    names = list(obs.pose_names)
    if not fits or len(names) < 2:
        return
    used = np.unique(pid)
    slot = {int(p): i for i, p in enumerate(used)}
    xs = np.array([slot[int(p)] for p in pid], float)
    width = max(W, 30.0 * used.size)
    y_max = max(max(float(np.max(np.abs(r.residual_g))) * 1e3 for r in fits.values()), 1e-6)
    rate = obs_drivers(obs).get("dtemp_degC_per_s", np.zeros(obs.n))

    def sx(x):
        return (np.asarray(x, float) + 0.5) / used.size * width

    def sy(y):
        return -np.asarray(y, float) / y_max * (H / 2)

    for label, res in fits.items():
        ent = f"{SCATTER}/pose/{slug(label)}"
        frame = [[0, -H / 2], [width, -H / 2], [width, H / 2], [0, H / 2], [0, -H / 2]]
        rec.log_static(
            f"{ent}/frame",
            rr.LineStrips2D(
                [frame, [[0, 0], [width, 0]]], colors=[(150, 150, 150), (110, 110, 110)], radii=0.6
            ),
            "scatter2d",
        )
        pos = [[float(sx(i)), H / 2 + 10 + 10 * (i % 2)] for i in range(used.size)]
        pos += [[-8, float(sy(v))] for v in (y_max, 0.0, -y_max)]
        txt = [names[int(p)] for p in used] + [f"{v:+.3g} mg" for v in (y_max, 0.0, -y_max)]
        rec.log_static(
            f"{ent}/ticks",
            rr.Points2D(pos, labels=txt, radii=0.1, colors=[(200, 200, 200)] * len(txt)),
            "scatter2d",
        )
        legend = "window residuals by pose: x red, y green, z blue (light: cooling)"
        rec.log_static(
            f"{ent}/legend", rr.Points2D([[width / 2, -H / 2 - 12]], labels=[legend], radii=0.1), "scatter2d"
        )
        r_mg = 1e3 * np.asarray(res.residual_g, float)
        for i, a in enumerate("xyz"):
            col = np.array(AXIS_COLORS[i])
            light = (col + (255 - col) * 0.6).astype(int)
            colors = np.where((rate >= 0)[:, None], col, light).astype(np.uint8)
            pts = np.column_stack([sx(xs + 0.25 * (i - 1)), sy(r_mg[:, i])])
            rec.log_static(f"{ent}/{a}", rr.Points2D(pts, colors=colors, radii=2.2), "scatter2d")


def log_residuals_vs_drivers(
    rec,
    obs: ObsTable,
    fits: Mapping[str, FitResult],
    contributions: Mapping[str, np.ndarray] | None = None,
) -> None:
    """Residual-vs-driver plots of the labelled fits (e.g. {'before: model3': ..., 'after: ...': ...}),
    and the window residuals by pose (named)."""
    log_panels(rec, panels(obs, fits, contributions))
    log_pose_panels(rec, obs, fits)


def log_diagnosis_residuals(rec, diag, obs: ObsTable) -> None:
    """diagnose --rrd: the model's residuals against each driver with the chosen candidate's
    predicted contribution drawn over them, and the residuals once the candidate is added."""
    before = f"{diag.model.name}"
    fits = {before: diag.fit}
    contrib = None
    if diag.best is not None and diag.best in diag.fits:
        after = diag.fits[diag.best]
        fits[f"+{diag.best}"] = after
        contrib = {before: contribution_g(diag.fit, after, obs)}
    log_residuals_vs_drivers(rec, obs, fits, contrib)


def log_workbench_residuals(rec, obs: ObsTable, start: FitResult, final: FitResult) -> None:
    """workbench --rrd: residuals of the start model (with what the added effects predict drawn
    over them) and of the final model, against each driver."""
    fits = {f"start {start.model.name}": start}
    contrib = None
    if final.model.name != start.model.name:
        fits[f"final {final.model.name}"] = final
        contrib = {f"start {start.model.name}": contribution_g(start, final, obs)}
    log_residuals_vs_drivers(rec, obs, fits, contrib)
