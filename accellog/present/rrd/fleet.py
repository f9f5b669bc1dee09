"""Rerun recording of a fleet report: parameters over time per device, and the fleet scatter.

Entities (timeline ``session_time``: the session's wall-clock start):

- ``fleet/devices/<device>/<param>``       Scalars: value, and value +- 1 sigma as two thin lines;
- ``fleet/devices/<device>/recalibrate``   TextLog at the session where a flagged change ends;
- ``fleet/scatter/bias_mg``                Points2D (static): b_x vs b_y (mg) of each device's latest
                                           session, flagged devices red, labels = device;
- ``fleet/scatter/scale_pct``              Points2D (static): S_xx - 1 vs S_yy - 1 (%);
- ``fleet/summary``                        TextDocument (markdown): flagged devices and outliers.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from accellog.present.rrd.recording import RunRecording

TIMELINE = "session_time"
OK_COLOR = (80, 160, 230)
FLAG_COLOR = (230, 60, 50)


def _blueprint(devices: list[str]):
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(
                rrb.Spatial2DView(name="zero-g offset b_x vs b_y (mg)", origin="/fleet/scatter/bias_mg"),
                rrb.Spatial2DView(name="sensitivity S_xx-1 vs S_yy-1 (%)", origin="/fleet/scatter/scale_pct"),
                rrb.TextDocumentView(name="summary", origin="/fleet/summary"),
            ),
            rrb.Tabs(
                *[
                    rrb.TimeSeriesView(name=d, origin=f"/fleet/devices/{d}")
                    for d in devices[:64]  # a viewer tab per device; larger fleets: browse the tree
                ]
            ),
        ),
        collapse_panels=True,
    )


def _log_device(rec, h: Any) -> None:
    import rerun as rr

    t_ns = np.array([r.get("start_time_unix_ns") or 0 for r in h.sessions], dtype="datetime64[ns]")
    names = h.sessions[0]["param_names"]
    vals = np.array([r["values"] for r in h.sessions], float)
    sig = np.array([r["sigmas"] for r in h.sessions], float)
    color = FLAG_COLOR if h.recalibrate else OK_COLOR
    for i, name in enumerate(names):
        ent = f"fleet/devices/{h.device}/{name}"
        rec.log(
            ent,
            rr.SeriesLines(names=[name, "-1σ", "+1σ"], colors=[color, (150, 150, 150), (150, 150, 150)]),
            static=True,
        )
        cols = np.stack([vals[:, i], vals[:, i] - sig[:, i], vals[:, i] + sig[:, i]], axis=1)
        rec.send_columns(
            ent, indexes=[rr.TimeColumn(TIMELINE, timestamp=t_ns)], columns=rr.Scalars.columns(scalars=cols)
        )
    for c in h.flagged:
        rec.set_time(TIMELINE, timestamp=np.datetime64(c.to_time_unix_ns, "ns"))
        rec.log(
            f"fleet/devices/{h.device}/recalibrate",
            rr.TextLog(f"{c.param} changed by {c.delta:+.4g} {c.unit} ({c.z:.3g} σ)", level="WARN"),
        )


def _scatter(rec, rep: Any, px: str, py: str, scale: float, offset: float, entity: str) -> None:
    import rerun as rr

    devs = [d for d in sorted(rep.latest) if {px, py} <= set(rep.latest[d]["param_names"])]
    if not devs:
        return
    flagged = {h.device for h in rep.flagged}
    pts = []
    for d in devs:
        r = rep.latest[d]
        v = dict(zip(r["param_names"], r["values"], strict=True))
        pts.append(((v[px] - offset) * scale, (v[py] - offset) * scale))
    rec.log(
        entity,
        rr.Points2D(
            np.array(pts),
            labels=devs,
            colors=[FLAG_COLOR if d in flagged else OK_COLOR for d in devs],
            radii=0.4 if scale == 1000.0 else 0.02,
        ),
        static=True,
    )


def write_fleet_recording(rep: Any, sink: str) -> None:
    """Write the report's recording to a sink ('save:FILE.rrd', 'spawn', 'connect[:URL]')."""
    import rerun as rr

    r = RunRecording(sink, app_id="accellog-fleet", blueprint=_blueprint([h.device for h in rep.devices]))
    try:
        rec = r.rec
        for h in rep.devices:
            _log_device(rec, h)
        _scatter(rec, rep, "b_x", "b_y", 1000.0, 0.0, "fleet/scatter/bias_mg")
        _scatter(rec, rep, "S_xx", "S_yy", 100.0, 1.0, "fleet/scatter/scale_pct")
        lines = [
            f"# fleet report ({rep.model})",
            "",
            f"{len(rep.devices)} devices, k = {rep.k_sigma:g} σ",
            "",
        ]
        lines += [f"- **recalibrate {h.device}**: {len(h.flagged)} changes" for h in rep.flagged] or [
            "- no device flagged"
        ]
        lines += ["", f"outliers: {', '.join(rep.outliers) or 'none'}", f"errors: {len(rep.errors)} sessions"]
        rec.log("fleet/summary", rr.TextDocument("\n".join(lines), media_type="text/markdown"), static=True)
    except BaseException:
        r.abort()
        raise
    r.close()
