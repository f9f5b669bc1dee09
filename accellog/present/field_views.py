"""Pictures of a calibration from stops (a robot's run, a hand-carried device; `fit RUN --prior LAB
--rrd F.rrd`): which gravity directions the stops saw, the gravity-norm residual per stop before and
after, and the gyro bias against temperature.

- /field/sphere: the stops' gravity directions (unit vectors of the calibrated specific force, in
  the sensor frame) on the unit sphere, with the six van Hees caps (an axis past +-0.3 g: the rings
  where that axis reads +-0.3 g) and the three great circles to read it by; a stop is drawn in the
  colour of the axis it reads most of; the document /docs/field/caps names the caps seen and not.
- /charts/field/norm_residual: |f| - g per stop (mg), before (the prior's calibration; without a
  prior the raw reading) and after the fit (their table and RMS: /docs/field/norm_residual).
- /field/gyro_bias: the gyro bias curve b0 + b_T (T - T_ref) per axis (deg/s) with +-1 sigma
  (sqrt(s_b0^2 + s_bT^2 dT^2): the coefficients' correlation is not stored) over the stops'
  temperatures, on the timeline GYRO_TEMP_TIMELINE (temperature in mdegC).
"""

from __future__ import annotations

import numpy as np

from accellog.present.rrd.bars2d import log_bar_groups
from accellog.present.rrd.entities import CHARTS

FIELD = "field"
GYRO_TEMP_TIMELINE = "temperature_mdegC"
CAP_G = 0.3
"""van Hees et al. 2014: an axis covered when it reads beyond +-0.3 g at some stop."""
AXIS_RGB = ((230, 60, 60), (60, 170, 60), (60, 100, 230))
GREY = (150, 150, 150)


def _circle(normal_axis: int, offset: float, n: int = 64) -> np.ndarray:
    """(n+1, 3) points of the circle on the unit sphere where component normal_axis = offset."""
    a = np.linspace(0.0, 2 * np.pi, n + 1)
    r = np.sqrt(max(1.0 - offset**2, 0.0))
    others = [k for k in range(3) if k != normal_axis]
    p = np.zeros((n + 1, 3))
    p[:, normal_axis] = offset
    p[:, others[0]], p[:, others[1]] = r * np.cos(a), r * np.sin(a)
    return p


def stop_colors(ups: np.ndarray) -> list[tuple[int, int, int]]:
    """Per stop: the colour of the axis it reads most of (the cap it is deepest in)."""
    return [AXIS_RGB[int(np.argmax(np.abs(u)))] for u in ups]


def caps_seen(ups: np.ndarray) -> str:
    """'caps seen: +z; not seen: +x, -x, +y, -y, -z' (van Hees: every axis past +-CAP_G g)."""
    caps = [f"{s}{a}" for a in "xyz" for s in "+-"]
    seen = [c for c in caps if np.any(("+-".index(c[0]) * -2 + 1) * ups[:, "xyz".index(c[1])] > CAP_G)]
    missing = [c for c in caps if c not in seen]
    return f"caps seen: {', '.join(seen) or 'none'}; not seen: {', '.join(missing) or 'none'}"


def log_field_fit(rec, outcome) -> None:
    """The pictures of a fit from stops (module doc): outcome is a stages.FitOutcome."""
    import rerun as rr

    from accellog.calibrate.model.fit import obs_drivers
    from accellog.present.views import pose_means

    fit, obs, cal = outcome.fit, outcome.obs, outcome.cal
    meas = np.asarray(obs.meas_g, float)
    drv = obs_drivers(obs)
    after = fit.model.correct(fit.theta, meas, drv)
    names, f_after = pose_means(obs, after)
    ups = f_after / np.linalg.norm(f_after, axis=1, keepdims=True)
    rec.log_static(f"{FIELD}/sphere/stops", rr.Points3D(ups, radii=0.03, colors=stop_colors(ups), labels=names),
                   role="field3d")  # fmt: skip
    caps = [_circle(k, s * CAP_G) for k in range(3) for s in (-1.0, 1.0)]
    rec.log_static(f"{FIELD}/sphere/caps", rr.LineStrips3D(caps, colors=[AXIS_RGB[k] for k in range(3) for _ in "+-"],
                   radii=0.004), role="field3d")  # fmt: skip
    rec.log_document(
        f"{FIELD}/caps", f"{len(ups)} stops; {caps_seen(ups)} (van Hees 2014: each axis past +-{CAP_G:g} g)\n"
    )
    grid = [_circle(k, 0.0) for k in range(3)]
    rec.log_static(f"{FIELD}/sphere/grid", rr.LineStrips3D(grid, colors=[(90, 90, 90)] * 3, radii=0.002),
                   role="field3d")  # fmt: skip
    truth = cal.truth_g
    before = meas
    if fit.prior_sources:
        prior_theta = np.array([r["prior"] for r in fit.prior_sources], float)
        before = fit.model.correct(prior_theta, meas, drv)
    _, f_before = pose_means(obs, before)
    res = np.c_[np.linalg.norm(f_before, axis=1) - truth, np.linalg.norm(f_after, axis=1) - truth] * 1e3
    what = "prior" if fit.prior_sources else "raw"
    log_bar_groups(rec, f"{CHARTS}/{FIELD}/norm_residual", names, [f"before ({what})", "after"],
                   [GREY, (60, 100, 230)], res, unit="mg")  # fmt: skip
    rms = np.sqrt(np.mean(res**2, axis=0))
    rows = [f"| {n} | {a:+.3f} | {b:+.3f} |" for n, (a, b) in zip(names, res, strict=True)]
    rec.log_document(f"{FIELD}/norm_residual", f"|f| - g per stop: RMS before ({what}) {rms[0]:.3f} mg, after "
                     f"{rms[1]:.3f} mg\n\n| stop | before (mg) | after (mg) |\n|---|---|---|\n" + "\n".join(rows) + "\n")  # fmt: skip
    g = cal.gyro
    temps = np.asarray(obs.temp_degC, float) if obs.temp_degC is not None else np.array([])
    if g is None or not temps.size or not np.isfinite(temps).all():
        return
    x = np.round(1000.0 * (np.linspace(temps.min(), temps.max(), 50) if np.ptp(temps) > 0 else temps[:1]))
    t = x / 1000.0  # degC, on the timeline's mdegC
    b = g.bias_at(t if "temp_bias" in g.effects else None)
    b = np.broadcast_to(b, (t.size, 3))
    dT = (t - g.t_ref_degC)[:, None]
    s_t = (
        np.nan_to_num(np.asarray(g.temp_bias_sigma_dps_per_degC, float)) if "temp_bias" in g.effects else 0.0
    )
    sig = np.sqrt(np.asarray(g.bias_sigma_dps) ** 2 + (s_t * dT) ** 2)
    names3 = [f"bias {a} (deg/s)" for a in "xyz"]
    band = [f"{a} {pm}1 sigma" for pm in "+-" for a in "xyz"]
    rec.log_curve(f"{FIELD}/gyro_bias/curve", GYRO_TEMP_TIMELINE, x, b, names3, "field_gyro")
    rec.log_curve(
        f"{FIELD}/gyro_bias/band", GYRO_TEMP_TIMELINE, x, np.c_[b + sig, b - sig], band, "field_gyro"
    )
