"""Presentation of a ``NoiseModel``: terminal tables and a log-log Allan plot in a Rerun recording.

The viewer has no logarithmic axes yet, so the Allan plot is a 2D view of (log10 tau [s], log10 ADEV
[SI unit]): per axis the measured ADEV (line strip + points), its 1-sigma confidence band (two thin
strips) and the fitted model; decade ticks are labelled points ("1 s", "10 s", "1e-3 m/s^2").

Entities: /noise/{accel,gyro}/{x,y,z}/{adev,lo,hi,model}, /noise/{sensor}/decades, /noise/summary (text).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from accellog.calibrate.noise.noise_model import NoiseModel, SensorNoise

AXIS_COLORS = {"x": (230, 80, 80), "y": (80, 190, 80), "z": (80, 120, 230)}


def _g(x: float, unit: str = "") -> str:
    if x != x:
        return "-"
    return f"{x:.3g}{(' ' + unit) if unit else ''}"


def _pm(v: float, s: float, detected: bool) -> str:
    return f"{v:.3g} ± {s:.2g}" if detected else f"< {v + 2 * s:.2g}"


_TERMS = (
    ("white", "N white", "white"),
    ("bias_instability", "B bias inst.", "bias_instability"),
    ("random_walk", "K rand. walk", "random_walk"),
)


def _datasheet_keys(acc: bool) -> dict[str, tuple[str, str, str]]:
    """term -> (value key, sigma key, unit) of SensorNoise.datasheet()."""
    if acc:
        return {
            "white": ("white_ug_per_rtHz", "white_sigma_ug_per_rtHz", "ug/√Hz"),
            "bias_instability": ("bias_instability_ug", "bias_instability_sigma_ug", "ug"),
            "random_walk": ("random_walk_ug_per_s_rtHz", "random_walk_sigma_ug_per_s_rtHz", "ug/s/√Hz"),
        }
    return {
        "white": ("arw_deg_per_rth", "arw_sigma_deg_per_rth", "deg/√h"),
        "bias_instability": ("bias_instability_deg_per_h", "bias_instability_sigma_deg_per_h", "deg/h"),
        "random_walk": ("rrw_deg_per_h_rth", "rrw_sigma_deg_per_h_rth", "deg/h/√h"),
    }


def sensor_table(s: SensorNoise):
    """A rich Table: one row per axis and term, SI and datasheet units side by side."""
    from rich import box
    from rich.table import Table

    unit = s.si_unit
    si_units = {"white": f"{unit}/√Hz", "bias_instability": unit, "random_walk": f"{unit}/s/√Hz"}
    keys = _datasheet_keys(s.sensor == "accel")
    t = Table(title=f"{s.sensor} noise (1 sigma; '<' = not resolved: 2-sigma bound)", box=box.SIMPLE_HEAD)
    for col in ("axis", "term", "SI", "", "datasheet", "", "min. T"):
        t.add_column(col, justify="right" if col in ("SI", "datasheet") else "left")
    for a in s.axes:
        d = s.datasheet(a)
        for i, (name, label, _) in enumerate(_TERMS):
            p = getattr(a, name)
            vk, sk, du = keys[name]
            t.add_row(
                a.axis if i == 0 else "",
                label,
                _pm(p.value, p.sigma, p.detected),
                si_units[name],
                _pm(d[vk], d[sk], p.detected),
                du,
                "-" if p.min_duration_s is None else _dur(p.min_duration_s),
                end_section=i == len(_TERMS) - 1,
            )
    return t


def _dur(s: float) -> str:
    if s < 1:
        return "< 1 s"
    if s < 120:
        return f"{s:.0f} s"
    if s < 7200:
        return f"{s / 60:.0f} min"
    return f"{s / 3600:.1f} h"


def summary_lines(m: NoiseModel) -> list[str]:
    """Facts and flags under the tables."""
    out = [f"{m.source}: {m.n_samples} samples, {_dur(m.duration_s)} at {m.rate_hz:g} Hz"]
    for s in m.sensors():
        if s.quantisation_flag:
            out.append(
                f"{s.sensor}: quantisation flagged (sample sigma < 2 LSB or Q resolved); quantum {_g(s.quantum_si or math.nan, s.si_unit)}"
            )
    if m.temp_range_degC is not None:
        lo, hi = m.temp_range_degC
        out.append(f"die temperature {lo:.2f} .. {hi:.2f} degC")
    for seg in m.temp_segments:
        out.append(
            f"temperature-driven: {seg.start_s:.0f} .. {seg.end_s:.0f} s ({seg.rate_degC_per_min:+.2f} degC/min)"
        )
    out.extend(m.notes)
    k = m.kalibr()
    if k:
        out.append("Kalibr (worst axis): " + ", ".join(f"{n} = {v:.3g}" for n, v in k.items()))
    out.append(
        "N is the Allan/IEEE/Kalibr white noise (ADEV(1 s)); a datasheet's one-sided density is sqrt(2) N"
    )
    return out


def print_noise(m: NoiseModel) -> None:
    from rich.console import Console

    con = Console()
    for s in m.sensors():
        con.print(sensor_table(s))
    for line in summary_lines(m):
        con.print(line, highlight=False)


# -- Rerun ---------------------------------------------------------------------------------------------


def noise_blueprint(m: NoiseModel):
    import rerun.blueprint as rrb

    views = [
        rrb.Spatial2DView(
            origin=f"/noise/{s.sensor}", name=f"{s.sensor}: log10 ADEV ({s.si_unit}) vs log10 tau (s)"
        )
        for s in m.sensors()
    ]
    return rrb.Blueprint(
        rrb.Horizontal(*views, rrb.TextDocumentView(origin="/noise/summary", name="summary"))
    )


def _strip(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    ok = np.isfinite(x) & np.isfinite(y)
    return np.stack([x[ok], -y[ok]], axis=1)  # image-style y axis points down: plot -log10 so up is larger


def log_noise(rrd: str | Path, m: NoiseModel) -> None:
    """Write the Allan plots and the summary of ``m`` to the .rrd file ``rrd``."""
    from accellog.present.rrd.recording import RunRecording
    from accellog.present.rrd.sdk import rerun_sdk

    rr = rerun_sdk()  # imported the one way (present.rrd.sdk: collector paused, rerun's sink logs quiet)

    with RunRecording(f"save:{rrd}", blueprint=noise_blueprint(m)) as run:
        rec = run.rec
        for s in m.sensors():
            ys = []
            for a in s.axes:
                lt = np.log10(a.tau_s)
                base = f"noise/{s.sensor}/{a.axis}"
                col = AXIS_COLORS[a.axis]
                ly = np.log10(np.maximum(a.adev, 1e-300))
                ys.append(ly)
                rec.log(
                    f"{base}/adev",
                    rr.LineStrips2D([_strip(lt, ly)], colors=[col], radii=0.01, labels=[a.axis]),
                    static=True,
                )
                rec.log(f"{base}/points", rr.Points2D(_strip(lt, ly), colors=[col], radii=0.025), static=True)
                for name, v in (("lo", a.adev_lo), ("hi", a.adev_hi)):
                    rec.log(
                        f"{base}/{name}",
                        rr.LineStrips2D(
                            [_strip(lt, np.log10(np.maximum(v, 1e-300)))], colors=[(*col, 110)], radii=0.004
                        ),
                        static=True,
                    )
                model = np.log10(np.maximum(a.model_adev(a.tau_s), 1e-300))
                rec.log(
                    f"{base}/model",
                    rr.LineStrips2D([_strip(lt, model)], colors=[(200, 200, 200)], radii=0.006),
                    static=True,
                )
            lt_all = np.log10(s.axes[0].tau_s)
            _log_decades(rec, f"noise/{s.sensor}/decades", lt_all, np.concatenate(ys), s.si_unit)
        rec.log(
            "noise/summary",
            rr.TextDocument("\n\n".join(summary_lines(m)), media_type="text/markdown"),
            static=True,
        )


def _log_decades(rec, entity: str, lt: np.ndarray, ly: np.ndarray, unit: str) -> None:
    """Labelled decade ticks along the two axes of the log-log plot."""
    import rerun as rr

    ly = ly[np.isfinite(ly)]
    x0, x1 = math.floor(lt.min()), math.ceil(lt.max())
    y0, y1 = math.floor(ly.min()), math.ceil(ly.max())
    pts, labels = [], []
    for k in range(x0, x1 + 1):
        pts.append((k, -(y0 - 0.3)))
        labels.append(f"{10.0**k:g} s")
    for k in range(y0, y1 + 1):
        pts.append((x0 - 0.3, -k))
        labels.append(f"1e{k} {unit}")
    rec.log(
        entity,
        rr.Points2D(pts, labels=labels, radii=0.02, colors=[(160, 160, 160)], show_labels=True),
        static=True,
    )
