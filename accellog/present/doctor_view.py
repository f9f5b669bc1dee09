"""Present a doctor report (accellog.flows.doctor.DoctorReport, duck-typed: this layer sits below flows):
rich tables, and a Rerun recording with the sample-interval histogram, the interval over time, gaps
and other findings on the timeline, and the report as a document."""

from __future__ import annotations

import numpy as np
from rich.table import Table

from accellog.core.device import DeviceKey

HIST_BINS = 60


def tables(r) -> list[Table]:
    """Summary, findings and supported calibrations."""
    s = Table(title=f"doctor: {r.path}", show_header=False)
    s.add_column("what", style="bold")
    s.add_column("value")
    s.add_row("source", r.source)
    s.add_row("device", DeviceKey.from_dict(r.device).describe())
    s.add_row("samples", f"{r.samples} over {r.duration_s:.6g} s")
    iv = r.interval_ms
    odd = " [red](not an IMU rate: see findings)[/]" if any(x.kind == "rate" for x in r.findings) else ""
    s.add_row("rate", f"{r.rate_hz:.6g} Hz{odd} (interval median {iv.get('median', 0):.4g} ms, "
              f"p01 {iv.get('p01', 0):.4g} ms, p99 {iv.get('p99', 0):.4g} ms, max {iv.get('max', 0):.4g} ms)")  # fmt: skip
    s.add_row("jitter", f"{100 * r.jitter_rel:.3g} % of the interval (robust)")
    t = r.temperature_degC
    s.add_row(
        "temperature",
        "none" if t is None else f"{t['min']:.2f} .. {t['max']:.2f} degC (span {t['span']:.2f})",
    )
    ev = r.events
    s.add_row("events", ", ".join(f"{v} {k}" for k, v in ev["by_kind"].items()) or "none")
    s.add_row(
        "still intervals", f"{len(r.still_intervals)} ({r.distinct_orientations} distinct orientations)"
    )
    s.add_row(
        "verdict", "[green]no defects found[/]" if r.healthy else f"[red]{len(r.findings)} defect(s)[/]"
    )
    f = Table(title="findings")
    for name in ("defect", "count", "detail", "first at (s)"):
        f.add_column(name)
    for x in r.findings:
        f.add_row(x.kind, str(x.count), x.detail, ", ".join(f"{v:.4g}" for v in x.t_s[:3]))
    c = Table(title="calibrations this log supports")
    for col in ("calibration", "ok", "why"):
        c.add_column(col)
    for x in r.supports:
        c.add_row(x.calibration, "[green]yes[/]" if x.ok else "[yellow]no[/]", x.why)
    return [s, f, c] if r.findings else [s, c]


def markdown(r) -> str:
    lines = [
        f"### doctor: {r.path}",
        "",
        f"{r.samples} samples, {r.duration_s:.6g} s, {r.rate_hz:.6g} Hz",
        "",
    ]
    lines += ["| defect | count | detail |", "|---|---|---|"]
    lines += [f"| {x.kind} | {x.count} | {x.detail} |" for x in r.findings] or ["| none | 0 | |"]
    lines += ["", "| calibration | ok | why |", "|---|---|---|"]
    lines += [f"| {x.calibration} | {'yes' if x.ok else 'no'} | {x.why} |" for x in r.supports]
    return "\n".join(lines) + "\n"


def log_doctor(rec, r, t_s: np.ndarray) -> None:
    """Into a RunRecording: doctor/interval_histogram (BarChart of interval counts, HIST_BINS bins from 0
    to 2x the median interval; the last bin holds everything longer), doctor/interval_ms over sensor
    time, doctor/findings (one text line per flagged time) and the report as a document."""
    import rerun as rr

    dt_ms = np.diff(np.asarray(t_s, float)) * 1e3
    med = r.interval_ms.get("median", 0.0) or 1.0
    edges = np.linspace(0.0, 2.0 * med, HIST_BINS + 1)
    counts = np.histogram(np.clip(dt_ms, 0.0, edges[-1]), bins=edges)[0].astype(np.float64)
    rec.rec.log("doctor/interval_histogram", rr.BarChart(counts), static=True)
    rec.rec.log("doctor/interval_histogram", rr.AnyValues(bin_width_ms=[edges[1] - edges[0]]), static=True)
    rec.log_series("doctor/interval_ms", t_s[1:], dt_ms, ["sample interval (ms)"], role="doctor", points=True)
    for x in r.findings:
        for t in x.t_s:
            rec.log_text("doctor/findings", t, f"{x.kind}: {x.detail}", level="WARN")
    rec.log_document("doctor/report", markdown(r))
