"""Pipeline results -> a Rerun recording (``accellog.present.rrd.RunRecording``) laid out for the question.

One function per kind of result, shared by ``accellog demo`` and the ``--rrd`` option of fit /
evaluate / drift / run / diagnose / track, so every run's recording looks the same:

- ``log_session``: raw and calibrated acceleration per axis over sensor time (g), the hold windows
  with their labels, temperature (degC) and events (gaps, overflows) on the same timeline;
- ``log_fit``: per pose, what the model predicts next to what was measured, and the parameter
  table with uncertainties as a document;
- ``log_evaluations``: the test session's integrated displacement per model (time series and 3D
  tracks side by side) and the seed-style tables;
- ``log_diagnosis`` / ``log_track_runs``: the workbench verdict and moving-robot tracks vs truth.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np
from rich.table import Table

from accellog.core.session import Session
from accellog.present.rrd.entities import slug_path
from accellog.present.tables import displacement_table, params_table, static_means_table

if TYPE_CHECKING:
    from accellog.calibrate.calfile.calibration import Calibration


def table_markdown(table: Table) -> str:
    """A rich Table as a markdown table (title as a heading, caption below)."""
    cols = table.columns
    header = [str(c.header) for c in cols]
    cells = [[str(v) for v in c._cells] for c in cols]
    rows = list(zip(*cells, strict=True)) if cells else []
    out = []
    if table.title:
        out.append(f"### {table.title}\n")
    out.append("| " + " | ".join(header) + " |")
    out.append("|" + "|".join("---" for _ in header) + "|")
    out.extend("| " + " | ".join(r) + " |" for r in rows)
    if table.caption:
        out.append(f"\n{table.caption}")
    return "\n".join(out) + "\n"


def log_session(
    rec, session: Session, *, calibrations: Mapping[str, Calibration] | None = None, prefix: str = ""
) -> None:
    """Raw (and calibrated) accel in g, gyro in deg/s, holds, temperature and events of a session."""
    name = prefix or "raw"
    rec.log_samples(name, session.t_s, session.sample_index, session.accel_g, "g", kind="accel")
    for label, cal in (calibrations or {}).items():
        corrected = cal.correct(session)
        rec.log_samples(
            f"{prefix} {label}".strip(), session.t_s, session.sample_index, corrected, "g", kind="accel"
        )
    if session.gyro_dps is not None:
        rec.log_samples(name, session.t_s, session.sample_index, session.gyro_dps, "deg/s", kind="gyro")
    if session.poses:
        rec.log_poses(session.poses)
    if session.temp_degC is not None:
        rec.log_temperature(session.t_s, session.temp_degC)
    if session.events:
        rec.log_events(session.events)


def pose_means(obs, values_g: np.ndarray) -> tuple[list[str], np.ndarray]:
    """Average window rows per pose (in pose order): names and (P,3) means (g)."""
    pid = np.asarray(obs.pose_id)
    out = np.array([values_g[pid == k].mean(axis=0) for k in range(len(obs.pose_names))])
    return list(obs.pose_names), out


def log_fit(rec, outcome, label: str | None = None) -> None:
    """Measured vs predicted per pose (residual bars per axis) and the parameter table."""

    fit = outcome.fit
    label = label or fit.model.name
    names, measured = pose_means(outcome.obs, np.asarray(outcome.obs.meas_g, float))
    _, predicted = pose_means(outcome.obs, np.asarray(fit.predicted_g, float))
    rec.log_residuals(label, names, measured, predicted)
    rec.log_document(
        f"parameters/{label}", table_markdown(params_table(outcome.cal, title=f"{label}: parameters"))
    )
    if fit.identification is not None:  # a fit from stops (a field session): its pictures too
        from accellog.present.field_views import log_field_fit

        log_field_fit(rec, outcome)


def log_evaluations(
    rec, evals: Sequence, *, truth_label: str | None = "truth (at rest)", group: str = "test"
) -> None:
    """Displacement tracks of a static test per calibration (+ after the drift model) and tables,
    at /tracks/{group}/{label} and /world/tracks/{group}/{label}."""

    t_ref = None
    for ev in evals:
        if ev.t_s is None or ev.disp_series_m is None:
            continue
        rec.log_track(f"{group}/{ev.label}", ev.t_s, ev.disp_series_m)
        if ev.disp_drift_series_m is not None:
            rec.log_track(f"{group}/{ev.label} + drift model", ev.t_s, ev.disp_drift_series_m)
        t_ref = ev.t_s
    if truth_label and t_ref is not None:
        rec.log_track(f"{group}/{truth_label}", t_ref[[0, -1]], np.zeros((2, 3)))
    if evals:
        md = table_markdown(static_means_table(evals)) + "\n" + table_markdown(displacement_table(evals))
        rec.log_document("results/static test", md)


def log_diagnosis(rec, diag, obs, label: str = "diagnose") -> None:
    """The workbench verdict, ranked candidates and strongest driver-signal correlations."""
    lines = [f"## {label}: {diag.model.name}", "", diag.verdict, ""]
    lines += ["| rank | effect | Δχ²/dof | p | identifiable | note |", "|---|---|---|---|---|---|"]
    for i, c in enumerate(diag.candidates[:12], 1):
        lines.append(
            f"| {i} | {c.get('effect')} | {_num(c.get('delta_chi2_dof'))} | {_num(c.get('p_value'))} | "
            f"{c.get('identifiable')} | {c.get('reason', '')} |"
        )
    if diag.advice:
        lines += ["", "### what to record next", *[f"- {a}" for a in diag.advice]]
    rec.log_document(f"workbench/{label}", "\n".join(lines) + "\n")
    names, measured = pose_means(obs, np.asarray(obs.meas_g, float))
    _, predicted = pose_means(obs, np.asarray(diag.fit.predicted_g, float))
    rec.log_residuals(f"{label} {diag.model.name}", names, measured, predicted)


def log_track_runs(rec, runs: Sequence, truth=None, group: str = "robot") -> None:
    """Moving-robot tracks per calibration next to the true path (time series and 3D), the
    position error over time (m) per calibration, the stops ZUPT used, and the error table."""

    if truth is not None:
        rec.log_track(f"{group}/truth", truth.t_s, truth.position_m)
    lines = [
        "| calibration | final error (m) | RMS error (m) | ZUPT stops | final error without ZUPT (m) |",
        "|---|---|---|---|---|",
    ]
    for r in runs:
        t, p = r.track.t_s, r.track.position_m
        rec.log_track(f"{group}/{r.name}", t, p)
        if truth is not None:
            ref = np.column_stack([np.interp(t, truth.t_s, truth.position_m[:, i]) for i in range(3)])
            err = np.linalg.norm(p - ref, axis=1)
            rec.log_series(
                f"errors/{group}/{slug_path(r.name)}", t, err, [f"{r.name} |error| (m)"], role="track_error"
            )
        if r.zupt is not None and len(r.zupt.intervals_s):
            iv = np.asarray(r.zupt.intervals_s, float).reshape(-1, 2)
            on = np.tile([1.0, 0.0], len(iv))  # 1 from each stop's start, 0 from its end
            rec.log_series(
                f"zupt/{group}/{slug_path(r.name)}",
                iv.ravel(),
                on,
                [f"{r.name}: ZUPT stop"],
                role="zupt",
                step=True,
            )
        e0 = r.error_without_zupt.final_error_m if r.error_without_zupt is not None else float("nan")
        lines.append(
            f"| {r.name} | {r.error.final_error_m:.3g} | {r.error.rms_error_m:.3g} | {r.error.zupt_stops} | {e0:.3g} |"
        )
    rec.log_document(f"results/{group} tracks", "\n".join(lines) + "\n")


def _num(v) -> str:
    if v is None:
        return "-"
    try:
        return f"{float(v):.3g}"
    except (TypeError, ValueError):
        return str(v)
