"""Rich tables of a fleet run and a fleet report (accellog.flows.fleet / fleet_report).

- `run_table`: sessions run / skipped / failed, throughput, scheduler;
- `errors_table`: one row per session that could not be calibrated, with its one-line message;
- `devices_table`: one row per device: key, sessions, "recalibrate" with the largest change
  (delta in the parameter's unit and in combined sigmas);
- `distribution_table`: per parameter the fleet mean +- std, range, datasheet limit, outliers.
"""

from __future__ import annotations

import datetime as _dt
from typing import Any

from rich.table import Table

from accellog.present.tables import fmt_pm


def _date(ns: int | None) -> str:
    if not ns:
        return "?"
    return _dt.datetime.fromtimestamp(ns / 1e9, _dt.timezone.utc).strftime("%Y-%m-%d")


def _delta(c: Any) -> str:
    """'b_x +19.9 mg (196 sigma)': a parameter change in a readable unit."""
    scale, unit = (
        (1000.0, "mg") if c.unit == "g" else (100.0, "%") if c.unit in ("", "1", "-") else (1.0, c.unit)
    )
    return f"{c.param} {c.delta * scale:+.3g} {unit} ({c.z:.3g} σ)"


def run_table(res: Any) -> Table:
    t = Table(title=f"fleet run: pipeline {res.pipeline!r} -> {res.table}")
    for c in ("sessions", "run", "skipped (unchanged)", "errors", "workers", "wall (s)", "tasks/s"):
        t.add_column(c, justify="right")
    t.add_row(
        str(res.n_sessions),
        str(res.n_run),
        str(res.n_skipped),
        str(len(res.errors)),
        f"{res.n_workers} ({res.scheduler or '-'})",
        f"{res.wall_s:.3g}",
        f"{res.tasks_per_s:.3g}" if res.n_run else "-",
    )
    return t


def errors_table(errors: list[tuple[str, str]] | list[dict[str, str]]) -> Table:
    t = Table(title="sessions not calibrated")
    t.add_column("session")
    t.add_column("error")
    for e in errors:
        s, m = (e["session"], e["error"]) if isinstance(e, dict) else e
        t.add_row(s, m)
    return t


def devices_table(rep: Any) -> Table:
    t = Table(title=f"devices ({rep.model}; recalibrate when a change exceeds {rep.k_sigma:g} combined σ)")
    for c in ("device", "key", "sessions", "first", "last", "status", "largest change"):
        # the flag and the dates are never cut ("recalib…"): the key and the change wrap instead
        t.add_column(
            c, no_wrap=c in ("sessions", "first", "last", "status"), min_width=11 if c == "status" else None
        )
    for h in rep.devices:
        first, last = h.sessions[0].get("start_time_unix_ns"), h.sessions[-1].get("start_time_unix_ns")
        status = "[bold red]recalibrate[/]" if h.recalibrate else "ok"
        change = h.flagged[0] if h.flagged else h.largest
        where = f" at {_date(change.to_time_unix_ns)}" if h.flagged else ""
        t.add_row(
            h.device,
            h.key.describe().removeprefix(h.device).strip(" ()"),
            str(len(h.sessions)),
            _date(first),
            _date(last),
            status,
            (_delta(change) + where + (f"; proposed {h.proposed}" if h.proposed else "")) if change else "-",
        )
    return t


def distribution_table(rep: Any) -> Table:
    t = Table(title=f"fleet distribution ({rep.model}, latest session per device) vs datasheet")
    for c in (
        "param",
        "mean ± std",
        "min",
        "max",
        "unit",
        "datasheet |dev| <",
        "outside limit",
        "robust outliers",
    ):
        t.add_column(c, justify="right" if c not in ("param", "unit") else "left")
    for p in rep.distributions:
        t.add_row(
            p.param,
            fmt_pm(p.mean, p.std),
            f"{p.min:.4g}",
            f"{p.max:.4g}",
            p.unit,
            "-" if p.limit is None else f"{p.limit:g}",
            ", ".join(p.outside_limit) or "-",
            ", ".join(p.robust_outliers) or "-",
        )
    return t
