"""Tables of the JSON artifacts the stages write (calibration files, evaluate/integrate/workbench --json).

`tables_for(d, name)` picks the tables by what the artifact contains; `accellog report` prints them.
"""

from __future__ import annotations

from typing import Any

from rich.table import Table

from accellog.calibrate.calfile.sections import FitInfo
from accellog.core.device import DeviceKey
from accellog.core.errors import InputError
from accellog.present.tables import fmt_pm, ladder_table

AXES = ("x", "y", "z")


def _params(d: dict, name: str) -> Table:
    model = d.get("model", {})
    t = Table(title=f"{name}: {model.get('name', '')} ({', '.join(model.get('terms', []))})")
    for c in ("parameter", "value ± 1σ", "unit"):
        t.add_column(c, justify="right" if c.startswith("value") else "left")
    for p in d["params"]:
        t.add_row(p["name"], fmt_pm(float(p["value"]), float(p.get("sigma") or 0.0)), p.get("unit", ""))
    fit = FitInfo.from_dict(d.get("fit"), name)
    if fit.chi2_dof is not None:
        rms_g = float("nan") if fit.rms_g is None else fit.rms_g
        t.caption = f"chi2/dof {fit.chi2_dof:.4g}, residual RMS {1000 * rms_g:.4g} mg"
    if d.get("device"):
        dev = DeviceKey.from_dict(d["device"]).describe()
        t.caption = f"{t.caption}\ndevice {dev}" if t.caption else f"device {dev}"
    return t


def _evaluations(rows: list[dict], name: str) -> list[Table]:
    t4 = Table(title=f"{name}: mean residual after calibration (m/s²)")
    t5 = Table(title=f"{name}: integrated displacement (m)")
    t4.add_column("model")
    t5.add_column("model")
    for a in AXES:
        t4.add_column(f"{a} mean", justify="right")
    t4.add_column("χ² noise/dof", justify="right")
    times = rows[0].get("displacement", {}).get("times_s", [])
    for ts in times:
        t5.add_column(f"at {ts:g} s (x, y, z)", justify="right")
    for r in rows:
        m, s = r["mean_residual_mps2"], r.get("sem_mps2", {})
        t4.add_row(
            r["label"],
            *(fmt_pm(m[a], s.get(a, 0.0)) for a in AXES),
            f"{r.get('chi2_noise_dof', float('nan')):.3g}",
        )
        disp = r.get("displacement", {})
        t5.add_row(r["label"], *(_vec(d) for d in disp.get("disp_m", [])))
        if disp.get("disp_after_drift_m"):
            t5.add_row(f"{r['label']} + drift model", *(_vec(d) for d in disp["disp_after_drift_m"]))
    return [t4, t5] if times else [t4]


def _vec(v) -> str:
    """'x, y, z' (4 significant digits), '-' where a value is missing (e.g. past the session's end)."""
    return "-" if v is None else ", ".join("-" if x is None else f"{x:.4g}" for x in v)


def tables_for(d: Any, name: str) -> list[Table]:
    """The tables of one JSON artifact, by what it contains; InputError for anything else."""
    if isinstance(d, dict) and d.get("format") == "accellog.calibration":
        return [_params(d, name)]
    if isinstance(d, dict) and "raw" in d and "calibrated" in d and d.get("kind") != "poses":
        return _evaluations([x for x in [d["raw"], *d["calibrated"]] if x], name)
    if isinstance(d, dict) and "ladder" in d:
        from accellog.calibrate.diagnosis.ladder import LadderRow

        return [ladder_table([LadderRow.from_dict(r) for r in d["ladder"]], title=f"{name}: model ladder")]
    if isinstance(d, dict) and "disp_end_m" in d and "displacement_at_s" in d:
        t = Table(title=f"{name}: {d.get('label', '')} displacement (m)")
        t.add_column("t (s)", justify="right")
        for a in AXES:
            t.add_column(f"{a} (m)", justify="right")
        for ts, v in d["displacement_at_s"].items():
            t.add_row(ts, *([f"{x:.4g}" for x in v] if v and None not in v else ["-"] * 3))
        t.add_row(f"{d['t_end_s']:.2f} (end)", *(f"{x:.4g}" for x in d["disp_end_m"]))
        return [t]
    raise InputError(
        "not an accellog artifact this command can render (calibration JSON, evaluate/integrate/workbench --json)",
        where=name,
    )
