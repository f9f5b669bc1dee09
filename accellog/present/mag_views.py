"""Presentation of a ``MagCalibration``: a terminal table and raw vs corrected samples on a sphere (Rerun).

Entities: /mag/raw (Points3D, uT, AK8963 axes), /mag/corrected (Points3D: A (m - h), on the sphere of radius
F), /mag/sphere (LineStrips3D: three great circles of radius F), /mag/hard_iron (the fitted centre),
/mag/summary (text).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from accellog.calibrate.mag.magnetometer import MagCalibration


def print_magcal(c: MagCalibration, source: str) -> None:
    from rich.console import Console
    from rich.table import Table

    t = Table(title=f"{source}: magnetometer calibration ('{c.form}', {c.n_samples} samples, AK8963 axes)")
    t.add_column("axis")
    t.add_column("hard iron h (uT)", justify="right")
    t.add_column("soft iron A (row, ± 1 sigma)")
    for i, ax in enumerate("xyz"):
        row = "  ".join(
            f"{v:+.4f}±{s:.4f}" for v, s in zip(c.soft_iron[i], c.soft_iron_sigma[i], strict=True)
        )
        t.add_row(ax, f"{c.hard_iron_uT[i]:+.2f} ± {c.hard_iron_sigma_uT[i]:.2f}", row)
    con = Console()
    con.print(t)
    con.print(
        f"field {c.field_uT:.2f} ± {c.field_sigma_uT:.2f} uT; residual RMS {c.residual_rms_uT:.3f} uT; "
        f"noise (second differences) {c.noise_uT:.3f} uT",
        highlight=False,
    )
    for tr in c.trends:
        con.print(
            f"residual vs {tr.driver}: chi2 {tr.chi2:.1f} (4 dof){' FLAGGED' if tr.flagged else ''}; "
            f"strength {tr.slope:.3g} ± {tr.slope_sigma:.2g} {tr.unit}",
            highlight=False,
        )
    for n in c.notes:
        con.print(n, highlight=False)


def _circles(r: float, n: int = 120) -> list[np.ndarray]:
    a = np.linspace(0, 2 * np.pi, n)
    c, s, z = r * np.cos(a), r * np.sin(a), np.zeros(n)
    return [np.column_stack(v) for v in ((c, s, z), (c, z, s), (z, c, s))]


def log_magcal(rrd: str | Path, c: MagCalibration, mag_uT: np.ndarray) -> None:
    """Write raw and corrected samples (and the sphere of radius F) to the .rrd file ``rrd``."""
    import rerun as rr
    import rerun.blueprint as rrb

    from accellog.present.rrd.recording import RunRecording

    bp = rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="/mag", name="magnetometer: raw (grey) and corrected (blue), uT"),
            rrb.TextDocumentView(origin="/mag/summary", name="summary"),
        )
    )
    with RunRecording(f"save:{rrd}", blueprint=bp) as run:
        rec = run.rec
        rec.log("mag/raw", rr.Points3D(mag_uT, colors=[(150, 150, 150)], radii=0.3), static=True)
        rec.log(
            "mag/corrected", rr.Points3D(c.correct(mag_uT), colors=[(70, 130, 230)], radii=0.3), static=True
        )
        rec.log(
            "mag/sphere",
            rr.LineStrips3D(_circles(c.field_uT), colors=[(200, 200, 200)], radii=0.1),
            static=True,
        )
        rec.log(
            "mag/hard_iron",
            rr.Points3D([c.hard_iron_uT], colors=[(230, 80, 80)], radii=1.0, labels=["h"]),
            static=True,
        )
        text = "\n\n".join([f"field {c.field_uT:.2f} uT, residual {c.residual_rms_uT:.3f} uT", *c.notes])
        rec.log("mag/summary", rr.TextDocument(text, media_type="text/markdown"), static=True)
